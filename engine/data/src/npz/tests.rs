use super::*;

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("talkin_npz_{}_{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn parse(b: &[u8]) -> Result<NdArray, NpzError> {
    parse_npy(b, Path::new("x.npz"), "a")
}

#[test]
fn round_trips_every_dtype() {
    let arrays = [
        NdArray::f64(&[2, 3], vec![1.5, -2.0, 0.0, 3.25, 1e-300, -7.0]).unwrap(),
        NdArray::f32(&[3], vec![0.5, 1.5, -2.5]).unwrap(),
        NdArray::new(vec![], ArrayData::I32(vec![30])).unwrap(),
        NdArray::new(vec![2], ArrayData::I64(vec![-1, 1 << 40])).unwrap(),
        NdArray::new(vec![2, 2], ArrayData::U8(vec![0, 1, 255, 7])).unwrap(),
        NdArray::new(vec![3], ArrayData::Bool(vec![true, false, true])).unwrap(),
        NdArray::new(vec![2, 55], ArrayData::U32(vec![4_294_967_295; 110])).unwrap(),
        NdArray::new(vec![], ArrayData::Str(vec!["smplx2020".into()])).unwrap(),
    ];
    for a in &arrays {
        let back = parse(&npy_bytes(a).unwrap()).unwrap();
        assert_eq!(&back, a);
    }
}

/// Every dtype and text width `npy_bytes` writes, pinned byte for byte: `descr` and data
/// as `np.save` writes them (numpy 2.4), the header's shape as npyz spells it (`(3, )`
/// where numpy writes `(3,)`; numpy reads both).
#[test]
fn npy_bytes_are_pinned_to_numpys_layout() {
    use ArrayData::*;
    let a = |shape: &[usize], data| NdArray::new(shape.to_vec(), data).unwrap();
    let text = |v: &[&str]| Str(v.iter().map(|s| s.to_string()).collect());
    let pinned = [
        (
            a(&[3], text(&["a", "héllo", ""])),
            "<U5",
            "(3, )",
            concat!(
                "610000000000000000000000000000000000000068000000e90000006c0000006c000000",
                "6f0000000000000000000000000000000000000000000000",
            ),
        ),
        // All empty: numpy's width is still 1.
        (
            a(&[2, 1], text(&["", ""])),
            "<U1",
            "(2, 1, )",
            "0000000000000000",
        ),
        // The width counts characters (code points), not UTF-8 bytes.
        (a(&[], text(&["😀x"])), "<U2", "()", "00f6010078000000"),
        (a(&[2], Bool(vec![true, false])), "|b1", "(2, )", "0100"),
        (a(&[2], I8(vec![-1, 7])), "|i1", "(2, )", "ff07"),
        (a(&[2], I16(vec![-300, 7])), "<i2", "(2, )", "d4fe0700"),
        (
            a(&[2], I32(vec![-70000, 7])),
            "<i4",
            "(2, )",
            "90eefeff07000000",
        ),
        (
            a(&[1, 2], I64(vec![-(1 << 40), 7])),
            "<i8",
            "(1, 2, )",
            "0000000000ffffff0700000000000000",
        ),
        (a(&[2], U8(vec![255, 7])), "|u1", "(2, )", "ff07"),
        (a(&[2], U16(vec![65535, 7])), "<u2", "(2, )", "ffff0700"),
        (
            a(&[2], U32(vec![4_000_000_000, 7])),
            "<u4",
            "(2, )",
            "00286bee07000000",
        ),
        (
            a(&[2], U64(vec![u64::MAX, 7])),
            "<u8",
            "(2, )",
            "ffffffffffffffff0700000000000000",
        ),
        (
            a(&[2], F32(vec![0.5, -1e30])),
            "<f4",
            "(2, )",
            "0000003fcaf249f1",
        ),
        (a(&[2, 0], F64(vec![])), "<f8", "(2, 0, )", ""),
    ];
    for (array, descr, shape, data) in pinned {
        let data: Vec<u8> = (0..data.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&data[i..i + 2], 16).unwrap())
            .collect();
        let dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
        let expected = raw_npy_bytes(&dict, &data);
        assert_eq!(npy_bytes(&array).unwrap(), expected, "{descr} {shape}");
    }
}

#[test]
fn fortran_big_endian_and_scalars() {
    // np.asfortranarray(np.arange(6, dtype='>i4').reshape(2, 3)).
    let data: Vec<u8> = [0i32, 3, 1, 4, 2, 5]
        .iter()
        .flat_map(|v| v.to_be_bytes())
        .collect();
    let b = raw_npy_bytes(
        "{'descr': '>i4', 'fortran_order': True, 'shape': (2, 3), }",
        &data,
    );
    let a = parse(&b).unwrap();
    assert_eq!(a.to_i64().unwrap(), vec![0, 1, 2, 3, 4, 5]);
    assert_eq!(a.shape(), &[2, 3]);
    let b = raw_npy_bytes(
        "{'descr': '<f8', 'fortran_order': False, 'shape': (), }",
        &120.0f64.to_le_bytes(),
    );
    assert_eq!(parse(&b).unwrap().scalar_f64(), Some(120.0));
}

#[test]
fn corrupt_input_is_an_error_naming_the_array() {
    let good = npy_bytes(&NdArray::f64(&[4], vec![1.0; 4]).unwrap()).unwrap();
    for cut in [0, 5, 9, 20, good.len() - 1] {
        let e = parse(&good[..cut]).unwrap_err().to_string();
        assert!(e.contains("x.npz") && e.contains("`a`"), "{cut}: {e}");
    }
    let mut long = good.clone();
    long.push(0);
    assert!(
        parse(&long)
            .unwrap_err()
            .to_string()
            .contains("needs 32 bytes")
    );
    let huge = raw_npy_bytes(
        "{'descr': '<f8', 'fortran_order': False, 'shape': (4294967296, 4294967296, 4294967296), }",
        &[],
    );
    assert!(parse(&huge).unwrap_err().to_string().contains("too large"));
    let nested = raw_npy_bytes(&format!("{}{}", "(".repeat(5000), ")".repeat(5000)), &[]);
    assert!(parse(&nested).is_err());
    let obj = object_npy_bytes(b"\x80\x04N.");
    assert!(matches!(parse(&obj), Err(NpzError::Pickled { .. })));
    let record = raw_npy_bytes(
        "{'descr': [('a', '<f4'), ('b', '<i4')], 'fortran_order': False, 'shape': (1,), }",
        &[0; 8],
    );
    assert!(matches!(parse(&record), Err(NpzError::DType { .. })));
}

#[test]
fn archives_read_by_name_and_skip_objects() {
    let dir = temp("archive");
    let file = dir.join("m.npz");
    let poses = NdArray::f32(&[2, 165], vec![0.25; 330]).unwrap();
    let mut w = NpzWriter::create(&file).unwrap();
    w.array("poses", &poses).unwrap();
    w.raw("joint2num", &object_npy_bytes(b"\x80\x02}q\x00."))
        .unwrap();
    w.finish().unwrap();
    let mut npz = Npz::open(&file).unwrap();
    assert_eq!(npz.names(), &["poses".to_string(), "joint2num".to_string()]);
    assert_eq!(npz.read("poses").unwrap(), poses);
    let all = npz.read_all().unwrap();
    assert_eq!(all.skipped, vec!["joint2num".to_string()]);
    assert_eq!(all.arrays.len(), 1);
    let e = npz
        .read_checked("poses", &[Dim::Any("N"), Dim::Is(156)])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("m.npz") && e.contains("`poses`") && e.contains("(N, 156)"),
        "{e}"
    );
    let e = npz
        .read_checked("trans", &[Dim::Any("N"), Dim::Is(3)])
        .unwrap_err();
    assert!(e.to_string().contains("`trans` is missing"), "{e}");

    // A truncated archive is an error, not a panic.
    let bytes = std::fs::read(&file).unwrap();
    for cut in [0, 10, bytes.len() / 2, bytes.len() - 10] {
        let t = dir.join(format!("cut{cut}.npz"));
        std::fs::write(&t, &bytes[..cut]).unwrap();
        let e = Npz::open(&t).and_then(|mut n| n.read("poses")).unwrap_err();
        assert!(e.to_string().contains(&format!("cut{cut}.npz")), "{e}");
    }
    // A corrupted data byte (stored member, CRC) is caught.
    let mut flipped = bytes.clone();
    let at = bytes.len() / 4;
    flipped[at] ^= 0x55;
    let t = dir.join("flipped.npz");
    std::fs::write(&t, &flipped).unwrap();
    assert!(Npz::open(&t).and_then(|mut n| n.read("poses")).is_err());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn non_finite_values_are_located() {
    let mut v = vec![0.0; 6];
    v[4] = f64::INFINITY;
    let a = NdArray::f64(&[2, 3], v).unwrap();
    let e = check_array(
        &a,
        Path::new("f.npz"),
        "trans",
        &[Dim::Any("N"), Dim::Is(3)],
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("f.npz") && e.contains("`trans`") && e.contains("[1, 1]"),
        "{e}"
    );
}
