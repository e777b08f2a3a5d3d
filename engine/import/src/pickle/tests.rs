//! Fixtures dumped by CPython 3.11 with numpy 1.26 (`pickle.dumps(obj, protocol=p)`), where
//! `obj = {'frame_000000': {'intrinsics': np.eye(3, dtype=np.float32),
//! 'distortions': np.zeros(5)}}` unless said otherwise; the protocol-3 and -4 streams are
//! the hex dumps quoted in the format notes byte for byte.

use std::path::Path;
use std::sync::Arc;

#[path = "../../../data/tests/support/proptest_config.rs"]
mod proptest_config;

use proptest::prelude::*;

use super::*;
use talkin_data::array::{ArrayData, NdArray};

/// `pickle.dumps(obj, protocol=2)`: bytes as `_codecs.encode(str, 'latin1')`.
const P2: &[&str] = &[
    "80027d7100580c0000006672616d655f30303030303071017d710228580a000000696e7472696e736963737103636e75",
    "6d70792e636f72652e6d756c746961727261790a5f7265636f6e7374727563740a7104636e756d70790a6e6461727261",
    "790a71054b00857106635f636f646563730a656e636f64650a7107580100000062710858060000006c6174696e317109",
    "86710a52710b87710c52710d284b014b034b0386710e636e756d70790a64747970650a710f5802000000663471108988",
    "877111527112284b0358010000003c71134e4e4e4affffffff4affffffff4b007471146289680758270000000000c280",
    "3f0000000000000000000000000000c2803f0000000000000000000000000000c2803f71156809867116527117747118",
    "62580b000000646973746f7274696f6e737119680468054b0085711a680b87711b52711c284b014b0585711d680f5802",
    "0000006638711e898887711f527120284b0368134e4e4e4affffffff4affffffff4b0074712162896807582800000000",
    "000000000000000000000000000000000000000000000000000000000000000000000000000000712268098671235271",
    "247471256275732e",
];

/// Protocol 3 (Python 3.7 + numpy 1.20, HumanNeRF's environment): GLOBAL, BINPUT.
const P3: &[&str] = &[
    "80037d7100580c0000006672616d655f30303030303071017d710228580a000000696e7472696e736963737103636e75",
    "6d70792e636f72652e6d756c746961727261790a5f7265636f6e7374727563740a7104636e756d70790a6e6461727261",
    "790a71054b008571064301627107877108527109284b014b034b0386710a636e756d70790a64747970650a710b580200",
    "00006634710c898887710d52710e284b0358010000003c710f4e4e4e4affffffff4affffffff4b007471106289432400",
    "00803f0000000000000000000000000000803f0000000000000000000000000000803f711174711262580b0000006469",
    "73746f7274696f6e737113680468054b008571146807877115527116284b014b05857117680b58020000006638711889",
    "8887711952711a284b03680f4e4e4e4affffffff4affffffff4b0074711b628943280000000000000000000000000000",
    "0000000000000000000000000000000000000000000000000000711c74711d6275732e",
];

/// Protocol 4 (Python 3.8-3.13): FRAME, STACK_GLOBAL, MEMOIZE.
const P4: &[&str] = &[
    "80049547010000000000007d948c0c6672616d655f303030303030947d94288c0a696e7472696e73696373948c156e75",
    "6d70792e636f72652e6d756c74696172726179948c0c5f7265636f6e7374727563749493948c056e756d7079948c076e",
    "6461727261799493944b0085944301629487945294284b014b034b03869468078c0564747970659493948c0266349489",
    "8887945294284b038c013c944e4e4e4affffffff4affffffff4b007494628943240000803f0000000000000000000000",
    "000000803f0000000000000000000000000000803f947494628c0b646973746f7274696f6e7394680668094b00859468",
    "0b87945294284b014b05859468108c02663894898887945294284b0368144e4e4e4affffffff4affffffff4b00749462",
    "894328000000000000000000000000000000000000000000000000000000000000000000000000000000009474946275",
    "732e",
];

/// Protocol 5: arrays as `numpy.core.numeric._frombuffer(BYTEARRAY8, dtype, shape, 'C')`.
const P5: &[&str] = &[
    "8005952d010000000000007d948c0c6672616d655f303030303030947d94288c0a696e7472696e73696373948c126e75",
    "6d70792e636f72652e6e756d65726963948c0b5f66726f6d627566666572949394289624000000000000000000803f00",
    "00000000000000000000000000803f0000000000000000000000000000803f948c056e756d7079948c05647479706594",
    "93948c02663494898887945294284b038c013c944e4e4e4affffffff4affffffff4b007494624b034b0386948c014394",
    "749452948c0b646973746f7274696f6e7394680628962800000000000000000000000000000000000000000000000000",
    "0000000000000000000000000000000000000000000094680a8c02663894898887945294284b03680e4e4e4e4affffff",
    "ff4affffffff4b007494624b05859468117494529475732e",
];

/// One camera matrix object in two frames: the second is `BINGET 13`.
const SHARED: &[&str] = &[
    "800495e7000000000000007d94288c0c6672616d655f303030303030947d948c0a696e7472696e73696373948c156e75",
    "6d70792e636f72652e6d756c74696172726179948c0c5f7265636f6e7374727563749493948c056e756d7079948c076e",
    "6461727261799493944b0085944301629487945294284b014b034b03869468078c0564747970659493948c0266349489",
    "8887945294284b038c013c944e4e4e4affffffff4affffffff4b007494628943240000803f0000000000000000000000",
    "000000803f0000000000000000000000000000803f94749462738c0c6672616d655f303030303031947d946803680d73",
    "752e",
];

/// `np.asfortranarray(np.arange(6).reshape(2, 3))`: data 0 3 1 4 2 5, flag NEWTRUE.
const FORTRAN: &[&str] = &[
    "800495ba000000000000008c156e756d70792e636f72652e6d756c74696172726179948c0c5f7265636f6e7374727563",
    "749493948c056e756d7079948c076e6461727261799493944b0085944301629487945294284b014b024b03869468038c",
    "0564747970659493948c02693894898887945294284b038c013c944e4e4e4affffffff4affffffff4b00749462884330",
    "000000000000000003000000000000000100000000000000040000000000000002000000000000000500000000000000",
    "947494622e",
];

/// numpy scalars (`scalar(dtype, bytes)`), None, a list, a tuple, ints of every width.
const SCALARS: &[&str] = &[
    "8004951e010000000000007d94288c0179948c156e756d70792e636f72652e6d756c74696172726179948c067363616c",
    "61729493948c056e756d7079948c0564747970659493948c02663894898887945294284b038c013c944e4e4e4affffff",
    "ff4affffffff4b007494624308000000000000e03f94869452948c017a94680468078c02663494898887945294284b03",
    "680b4e4e4e4affffffff4affffffff4b0074946243040000003f94869452948c016994680468078c0269389489888794",
    "5294284b03680b4e4e4e4affffffff4affffffff4b007494624308fdffffffffffffff94869452948c016e944e8c016c",
    "945d94284b014740040000000000008c016194888594658c0162944d2c018c03626967948a060000000000018c036e65",
    "67944afbffffff752e",
];

fn bytes(hex: &[&str]) -> Vec<u8> {
    let s: String = hex.concat();
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

fn parse(b: &[u8]) -> Result<Value, PickleError> {
    parse_pickle(b, Path::new("cameras.pkl"))
}

/// The value every `obj` fixture holds.
fn camera_value() -> Value {
    let eye: Vec<f32> = (0..9).map(|i| if i % 4 == 0 { 1.0 } else { 0.0 }).collect();
    Value::dict([(
        "frame_000000",
        Value::dict([
            (
                "intrinsics",
                Value::array(NdArray::f32(&[3, 3], eye).unwrap()),
            ),
            (
                "distortions",
                Value::array(NdArray::f64(&[5], vec![0.0; 5]).unwrap()),
            ),
        ]),
    )])
}

#[test]
fn every_protocol_reads_the_same_camera() {
    for (p, hex) in [(2, P2), (3, P3), (4, P4), (5, P5)] {
        let v = parse(&bytes(hex)).unwrap_or_else(|e| panic!("protocol {p}: {e}"));
        assert_eq!(v, camera_value(), "protocol {p}");
        let k = v.get("frame_000000").unwrap().get("intrinsics").unwrap();
        assert_eq!(
            k.as_array().unwrap().data(),
            &ArrayData::F32(vec![1., 0., 0., 0., 1., 0., 0., 0., 1.])
        );
    }
}

#[test]
fn numpy_2_module_names_read_too() {
    // numpy 2 writes `numpy._core.multiarray` (one byte longer, so FRAME 328).
    let mut b = bytes(P4);
    let old = b"\x8c\x15numpy.core.multiarray";
    let at = b.windows(old.len()).position(|w| w == old).unwrap();
    b.splice(
        at..at + old.len(),
        b"\x8c\x16numpy._core.multiarray".iter().copied(),
    );
    b[3..11].copy_from_slice(&328u64.to_le_bytes());
    assert_eq!(b.len(), 339);
    assert_eq!(parse(&b).unwrap(), camera_value());
}

#[test]
fn the_writer_writes_what_cpython_writes() {
    assert_eq!(write_protocol4(&camera_value()), bytes(P4));
    // The same array object in two frames is written once and fetched from the memo.
    let k = Arc::new(
        NdArray::f32(
            &[3, 3],
            (0..9).map(|i| if i % 4 == 0 { 1.0 } else { 0.0 }).collect(),
        )
        .unwrap(),
    );
    let shared = Value::dict([
        (
            "frame_000000",
            Value::dict([("intrinsics", Value::Array(Arc::clone(&k)))]),
        ),
        (
            "frame_000001",
            Value::dict([("intrinsics", Value::Array(k))]),
        ),
    ]);
    assert_eq!(write_protocol4(&shared), bytes(SHARED));
}

#[test]
fn memo_shares_the_built_array() {
    // The array is memoised (as 13) before its BUILD and fetched in frame 2 after it.
    let v = parse(&bytes(SHARED)).unwrap();
    let a = v
        .get("frame_000000")
        .unwrap()
        .get("intrinsics")
        .unwrap()
        .as_array()
        .unwrap();
    let b = v.get("frame_000001").unwrap().get("intrinsics").unwrap();
    assert_eq!(a.shape(), &[3, 3]);
    assert_eq!(b.as_array(), Some(a));
    let (Value::Array(x), Value::Array(y)) =
        (v.get("frame_000000").unwrap().get("intrinsics").unwrap(), b)
    else {
        unreachable!()
    };
    assert!(Arc::ptr_eq(x, y), "one array, shared");
}

#[test]
fn fortran_order_arrays_come_out_in_c_order() {
    let v = parse(&bytes(FORTRAN)).unwrap();
    let a = v.as_array().unwrap();
    assert_eq!(a.shape(), &[2, 3]);
    assert_eq!(a.to_i64().unwrap(), vec![0, 1, 2, 3, 4, 5]);
}

#[test]
fn scalars_lists_tuples_and_ints() {
    let v = parse(&bytes(SCALARS)).unwrap();
    assert_eq!(v.get("y"), Some(&Value::Float(0.5)));
    assert_eq!(v.get("z"), Some(&Value::Float(0.5)));
    assert_eq!(v.get("i"), Some(&Value::Int(-3)));
    assert_eq!(v.get("n"), Some(&Value::None));
    assert_eq!(
        v.get("l"),
        Some(&Value::List(vec![
            Value::Int(1),
            Value::Float(2.5),
            Value::Str("a".into()),
            Value::Tuple(vec![Value::Bool(true)]),
        ]))
    );
    assert_eq!(v.get("b"), Some(&Value::Int(300)));
    assert_eq!(v.get("big"), Some(&Value::Int(1 << 40)));
    assert_eq!(v.get("neg"), Some(&Value::Int(-5)));
}

#[test]
fn truncation_is_reported_at_the_right_offset() {
    let b = bytes(P4);
    // Inside the intrinsics' data (SHORT_BINBYTES at byte 175, 36 bytes).
    let e = parse(&b[..190]).unwrap_err().to_string();
    assert!(
        e.contains("cameras.pkl") && e.contains("byte 175") && e.contains("SHORT_BINBYTES"),
        "{e}"
    );
    assert!(e.contains("needs 36 bytes, 13 left"), "{e}");
    // Cut at an opcode boundary: the end is where STOP was expected.
    let e = parse(&b[..213]).unwrap_err().to_string();
    assert!(e.contains("byte 213") && e.contains("before STOP"), "{e}");
    assert!(parse(&[]).is_err());
}

#[test]
fn code_and_unknown_opcodes_are_refused_by_name() {
    // pickle.dumps(os.system) in protocol 2, then a REDUCE: never executed.
    let e = parse(b"\x80\x02cposix\nsystem\nq\x00X\x02\x00\x00\x00lsq\x01\x85q\x02Rq\x03.")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("byte 2") && e.contains("posix.system") && e.contains("not allowed"),
        "{e}"
    );
    let e = parse(b"\x80\x04\x81.").unwrap_err().to_string();
    assert!(
        e.contains("byte 2") && e.contains("NEWOBJ") && e.contains("0x81"),
        "{e}"
    );
    // An object array's state carries a list, not bytes.
    let mut obj = bytes(P4);
    let f4 = b"\x8c\x02f4";
    let at = obj.windows(3).position(|w| w == &f4[..3]).unwrap();
    obj[at + 2..at + 4].copy_from_slice(b"O8");
    assert!(
        parse(&obj)
            .unwrap_err()
            .to_string()
            .contains("object arrays")
    );
    // A list holding itself cannot be expanded.
    let e = parse(b"\x80\x04]\x94h\x00a.").unwrap_err().to_string();
    assert!(e.contains("holding itself"), "{e}");
}

#[test]
fn written_pickles_read_back() {
    let a = Arc::new(NdArray::new(vec![2, 2], ArrayData::U8(vec![0, 1, 2, 255])).unwrap());
    let v = Value::dict([
        (
            "big",
            Value::array(NdArray::f64(&[300, 300], (0..90_000).map(f64::from).collect()).unwrap()),
        ),
        (
            "ints",
            Value::List((0..2500).map(|i| Value::Int(i * 1000 - 7)).collect()),
        ),
        ("mask", Value::Array(Arc::clone(&a))),
        ("again", Value::Array(a)),
        (
            "flags",
            Value::array(NdArray::new(vec![2], ArrayData::Bool(vec![true, false])).unwrap()),
        ),
        (
            "name",
            Value::array(NdArray::new(vec![], ArrayData::Str(vec!["neutral".into()])).unwrap()),
        ),
        (
            "tuple",
            Value::Tuple(vec![
                Value::None,
                Value::Float(-1.5),
                Value::Str("é".into()),
                Value::Bytes(vec![1, 2]),
            ]),
        ),
        ("huge", Value::Int(-(1 << 50))),
    ]);
    let b = write_protocol4(&v);
    assert_eq!(parse(&b).unwrap(), v);
}

proptest! {
    #![proptest_config(proptest_config::config(0x91c_1e5))]

    #[test]
    fn arbitrary_bytes_never_panic(b in proptest::collection::vec(any::<u8>(), 0..512)) {
        let _ = parse(&b);
    }

    #[test]
    fn mutated_pickles_never_panic(
        which in 0usize..6,
        edits in proptest::collection::vec((any::<u16>(), any::<u8>(), 0u8..3), 1..8),
    ) {
        let mut b = bytes([P2, P3, P4, P5, SHARED, SCALARS][which]);
        for (at, byte, kind) in edits {
            let at = usize::from(at) % (b.len() + 1);
            match kind {
                0 if at < b.len() => b[at] = byte,
                1 => b.insert(at, byte),
                _ => b.truncate(at),
            }
        }
        let _ = parse(&b);
    }

    /// Opcodes whose length field claims up to 2^64 bytes, followed by a few: refused as
    /// truncated (nothing of the claimed size is allocated: `take` checks what is left
    /// first). FRAME's length is only a hint and is not held to it.
    #[test]
    fn absurd_lengths_are_refused(
        op in proptest::sample::select(vec![
            b'B', b'X', b'T', b'C', b'U', 0x8c, 0x8d, 0x8e, 0x96, 0x95,
        ]),
        len in prop_oneof![
            Just(u64::MAX),
            Just(1u64 << 40),
            Just(u64::from(u32::MAX)),
            Just(0x8000_0000u64),
            0u64..16,
        ],
        tail in proptest::collection::vec(any::<u8>(), 0..16),
        protocol in 2u8..6,
    ) {
        let width = match op {
            b'C' | b'U' | 0x8c => 1,
            b'B' | b'X' | b'T' => 4,
            _ => 8,
        };
        let mut b = vec![0x80, protocol, op];
        b.extend(&len.to_le_bytes()[..width]);
        b.extend(&tail);
        b.push(b'.');
        let claimed = len & (u64::MAX >> (64 - 8 * width));
        let parsed = parse(&b);
        if op != 0x95 && claimed > b.len() as u64 {
            prop_assert!(parsed.is_err(), "accepted a claim of {claimed} bytes");
        }
    }
}

/// Offsets and lengths of the FRAME opcodes in `bytes`, walking frame by frame.
fn frames(b: &[u8]) -> Vec<(usize, u64)> {
    let mut out = Vec::new();
    let mut at = 2;
    while at < b.len() && b[at] == 0x95 {
        let len = u64::from_le_bytes(b[at + 1..at + 9].try_into().unwrap());
        out.push((at, len));
        at += 9 + len as usize;
    }
    out
}

#[test]
fn large_pickles_are_framed_as_cpython_frames_them() {
    // HumanNeRF's mesh_infos.pkl layout for 1200 frames: CPython 3.11 + numpy 1.26 wrote
    // 1 266 347 bytes in 20 frames, the first three at these offsets with these lengths
    // and the last at 1 249 456 (16 882 bytes); frame boundaries depend only on sizes.
    let mut items = Vec::new();
    for i in 0..1200 {
        let x = i as f64;
        items.push((
            format!("frame_{i:06}"),
            Value::dict([
                (
                    "Rh",
                    Value::array(NdArray::f32(&[3], vec![x as f32; 3]).unwrap()),
                ),
                ("Th", Value::array(NdArray::f64(&[3], vec![x; 3]).unwrap())),
                (
                    "poses",
                    Value::array(NdArray::f32(&[72], vec![0.5; 72]).unwrap()),
                ),
                (
                    "joints",
                    Value::array(NdArray::f64(&[24, 3], vec![x; 72]).unwrap()),
                ),
            ]),
        ));
    }
    let b = write_protocol4(&Value::dict(items));
    assert_eq!(b.len(), 1_266_347);
    let f = frames(&b);
    assert_eq!(f.len(), 20);
    assert_eq!(&f[..3], &[(2, 65571), (65582, 65538), (131129, 65723)]);
    assert_eq!(f[19], (1_249_456, 16_882));
    assert_eq!(parse(&b).unwrap().as_dict().unwrap().len(), 1200);
}

/// What `write_protocol4` wrote for text arrays of several widths and for every byte
/// order (`|` for one-byte types, `<` otherwise) when this pin was taken: a regression
/// pin, not a CPython dump. (CPython with numpy makes a fresh `<U` dtype object per
/// array and does not share a dtype's code string with an equal dict key, so it writes
/// those again where these fetch them from the memo.)
const DTYPES: &[&str] = &[
    "80049586030000000000007d94288c056e616d6573948c156e756d70792e636f72652e6d756c74696172726179948c0c",
    "5f7265636f6e7374727563749493948c056e756d7079948c076e6461727261799493944b008594430162948794529428",
    "4b014b03859468058c0564747970659493948c02553594898887945294284b038c013c944e4e4e4b144b044b08749462",
    "89433c610000000000000000000000000000000000000068000000e90000006c0000006c0000006f0000000000000000",
    "000000000000000000000000000000947494628c05656d70747994680468074b008594680987945294284b014b024b01",
    "8694680e8c02553194898887945294284b0368124e4e4e4b044b044b087494628943080000000000000000947494628c",
    "05656d6f6a6994680468074b008594680987945294284b0129680e8c02553294898887945294284b0368124e4e4e4b08",
    "4b044b0874946289430800f6010078000000947494628c0a73616d655f776964746894680468074b0085946809879452",
    "94284b014b01859468118943146100000062000000630000006400000065000000947494628c05666c61677394680468",
    "074b008594680987945294284b014b028594680e8c02623194898887945294284b038c017c944e4e4e4affffffff4aff",
    "ffffff4b007494628943020100947494628c02693194680468074b008594680987945294284b014b028594680e683e89",
    "8887945294284b03683a4e4e4e4affffffff4affffffff4b00749462894302ff07947494628c02753194680468074b00",
    "8594680987945294284b014b028594680e6848898887945294284b03683a4e4e4e4affffffff4affffffff4b00749462",
    "894302ff07947494628c02693294680468074b008594680987945294284b014b028594680e6852898887945294284b03",
    "68124e4e4e4affffffff4affffffff4b00749462894304d4fe0700947494628c02753894680468074b00859468098794",
    "5294284b014b028594680e685c898887945294284b0368124e4e4e4affffffff4affffffff4b00749462894310ffffff",
    "ffffffffff0700000000000000947494628c02663894680468074b008594680987945294284b014b028594680e686689",
    "8887945294284b0368124e4e4e4affffffff4affffffff4b00749462894310000000000000e03f00000000000000c094",
    "7494628c0366386294680468074b008594680987945294284b014b018594686c89430800000000000008409474946275",
    "2e",
];

#[test]
fn the_writer_keeps_its_dtype_and_text_layout() {
    let text = |shape: Vec<usize>, v: &[&str]| {
        let v = v.iter().map(|s| s.to_string()).collect();
        Value::array(NdArray::new(shape, ArrayData::Str(v)).unwrap())
    };
    let array = |shape: Vec<usize>, data| Value::array(NdArray::new(shape, data).unwrap());
    let v = Value::dict([
        ("names", text(vec![3], &["a", "héllo", ""])),
        ("empty", text(vec![2, 1], &["", ""])),
        ("emoji", text(vec![], &["😀x"])),
        ("same_width", text(vec![1], &["abcde"])),
        ("flags", array(vec![2], ArrayData::Bool(vec![true, false]))),
        ("i1", array(vec![2], ArrayData::I8(vec![-1, 7]))),
        ("u1", array(vec![2], ArrayData::U8(vec![255, 7]))),
        ("i2", array(vec![2], ArrayData::I16(vec![-300, 7]))),
        ("u8", array(vec![2], ArrayData::U64(vec![u64::MAX, 7]))),
        ("f8", array(vec![2], ArrayData::F64(vec![0.5, -2.0]))),
        ("f8b", array(vec![1], ArrayData::F64(vec![3.0]))),
    ]);
    let written = write_protocol4(&v);
    assert_eq!(written, bytes(DTYPES));
    assert_eq!(parse(&written).unwrap(), v);
}
