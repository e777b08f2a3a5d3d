//! `talkin export`: the exported avatar is the rendered one (its mesh posed by the
//! engine's skinning and rasterised against `talkin render`'s silhouette and colour on
//! held-out frames), its GLB holds the rig, weights and animation, and bad input exits 1
//! naming the flag or file without leaving a file.
//!
//! The ignored `glb_in_validator_and_three` runs the Khronos validator and three.js in
//! headless Chromium (see its docs); `.ci/run` installs both.

mod common;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use glam::{DVec3, Vec3};
use talkin::avatar::Avatar;
use talkin::data::dataset::{Dataset, Split};
use talkin::export::rig::pose_vertices;
use talkin::export::{ExportedAvatar, SurfaceOptions, export_avatar};
use talkin::grids::SamplerKind;
use talkin::human::camera::Camera;
use talkin::render::avatar::RenderFrame;
use talkin::render::avatar::RenderedFrame;
use talkin::render::sequence::split_frames;
use talkin::train::train;

/// A one-identity scene (96 px high) and a run trained on it, made once.
fn scene() -> &'static (Dataset, PathBuf) {
    static SCENE: OnceLock<(Dataset, PathBuf)> = OnceLock::new();
    SCENE.get_or_init(|| {
        let dataset = common::synthetic_scene("export_data", 1, 96, 11);
        let run = common::temp_dir("export_run");
        let opts = common::small_train_opts(SamplerKind::Accelerated, 60);
        train(&dataset, &run, &opts, &mut |_| {}).unwrap();
        (dataset, run)
    })
}

/// A triangle mesh rasterised through `camera` (pixel centres, nearest surface wins):
/// per pixel, coverage and the interpolated vertex colour.
fn rasterise(
    camera: &Camera,
    positions: &[Vec3],
    colours: &[[f32; 3]],
    triangles: &[[u32; 3]],
) -> (Vec<bool>, Vec<[f32; 3]>) {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut depth = vec![f64::INFINITY; w * h];
    let mut colour = vec![[0.0f32; 3]; w * h];
    let projected: Vec<Option<DVec3>> = positions
        .iter()
        .map(|p| camera.project(p.as_dvec3()))
        .collect();
    for t in triangles {
        let [Some(a), Some(b), Some(c)] = t.map(|v| projected[v as usize]) else {
            continue;
        };
        let area = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
        if area.abs() < 1e-12 {
            continue;
        }
        let x0 = a.x.min(b.x).min(c.x).floor().max(0.0) as usize;
        let x1 = (a.x.max(b.x).max(c.x).ceil() as usize).min(w);
        let y0 = a.y.min(b.y).min(c.y).floor().max(0.0) as usize;
        let y1 = (a.y.max(b.y).max(c.y).ceil() as usize).min(h);
        for y in y0..y1 {
            for x in x0..x1 {
                let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                let wb = ((px - a.x) * (c.y - a.y) - (c.x - a.x) * (py - a.y)) / area;
                let wc = ((b.x - a.x) * (py - a.y) - (px - a.x) * (b.y - a.y)) / area;
                let wa = 1.0 - wb - wc;
                if wa < 0.0 || wb < 0.0 || wc < 0.0 {
                    continue;
                }
                let z = wa * a.z + wb * b.z + wc * c.z;
                let i = y * w + x;
                if z < depth[i] {
                    depth[i] = z;
                    let [ca, cb, cc] = t.map(|v| colours[v as usize]);
                    colour[i] = std::array::from_fn(|k| {
                        (wa * ca[k] as f64 + wb * cb[k] as f64 + wc * cc[k] as f64) as f32
                    });
                }
            }
        }
    }
    (depth.iter().map(|d| d.is_finite()).collect(), colour)
}

/// Silhouette IoU and the colour PSNR (dB) inside the box around both silhouettes, the
/// mesh over the render's background.
fn compare(
    render: &RenderedFrame,
    covered: &[bool],
    colour: &[[f32; 3]],
    background: [f32; 3],
) -> (f64, f64) {
    let w = render.width as usize;
    let person: Vec<bool> = render.opacity.iter().map(|&o| o >= 0.5).collect();
    let inter = person
        .iter()
        .zip(covered)
        .filter(|(a, b)| **a && **b)
        .count();
    let union = person
        .iter()
        .zip(covered)
        .filter(|(a, b)| **a || **b)
        .count();
    let (mut x0, mut x1, mut y0, mut y1) = (usize::MAX, 0, usize::MAX, 0);
    for i in (0..person.len()).filter(|&i| person[i] || covered[i]) {
        let (x, y) = (i % w, i / w);
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    let (mut se, mut n) = (0.0f64, 0usize);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let i = y * w + x;
            let mesh = if covered[i] { colour[i] } else { background };
            for k in 0..3 {
                se += (f64::from(mesh[k]) - f64::from(render.rgb[3 * i + k])).powi(2);
                n += 1;
            }
        }
    }
    let psnr = 10.0 * (1.0 / (se / n.max(1) as f64)).log10();
    (inter as f64 / union.max(1) as f64, psnr)
}

/// The render beside the posed mesh, `export_same_FRAME.png` in the target tmp dir.
fn write_side_by_side(
    render: &RenderedFrame,
    covered: &[bool],
    colour: &[[f32; 3]],
    background: [f32; 3],
    frame: usize,
) {
    let (w, h) = (render.width, render.height);
    let byte = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    let img = image::RgbImage::from_fn(2 * w, h, |x, y| {
        let i = (y * w + x % w) as usize;
        let c = if x < w {
            [
                render.rgb[3 * i],
                render.rgb[3 * i + 1],
                render.rgb[3 * i + 2],
            ]
        } else if covered[i] {
            colour[i]
        } else {
            background
        };
        image::Rgb(c.map(byte))
    });
    let file = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("export_same_{frame}.png"));
    img.save(file).unwrap();
}

/// For each of `frames` (dataset indices): the exported mesh posed by the engine's
/// skinning and rasterised, against the avatar's render: (IoU, PSNR).
fn same_avatar_scores(
    avatar: &Avatar,
    dataset: &Dataset,
    exported: &ExportedAvatar,
    frames: &[usize],
) -> Vec<(f64, f64)> {
    let (identity, model) = avatar.subject(&exported.subject).unwrap();
    frames
        .iter()
        .map(|&i| {
            let f = &dataset.frames[i];
            let render = avatar.render(identity, &f.params, &f.camera, None).unwrap();
            let posed = pose_vertices(
                &model.skeleton,
                &f.params,
                &exported.surface.positions,
                &exported.skin,
            );
            let (covered, colour) = rasterise(
                &f.camera,
                &posed,
                &exported.colours,
                &exported.surface.triangles,
            );
            let scores = compare(&render, &covered, &colour, avatar.background);
            write_side_by_side(&render, &covered, &colour, avatar.background, i);
            scores
        })
        .collect()
}

#[test]
fn posed_mesh_matches_the_render_on_held_out_frames() {
    let (dataset, run) = scene();
    let avatar = Avatar::load(run).unwrap();
    let name = &dataset.subjects[0].name;
    let frames = split_frames(dataset, Split::TestSame).unwrap();
    let opts = SurfaceOptions {
        resolution: 64,
        ..SurfaceOptions::default()
    };
    let exported = export_avatar(&avatar, name, &opts).unwrap();
    let scores = same_avatar_scores(&avatar, dataset, &exported, &frames[..3.min(frames.len())]);
    for (k, (iou, psnr)) in scores.iter().enumerate() {
        eprintln!("test_same frame {k}: silhouette IoU {iou:.3}, person-box PSNR {psnr:.2} dB");
        assert!(*iou >= 0.9, "frame {k}: IoU {iou:.3}");
    }
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A BEAT2 motion of `n` frames waving the left arm (its shoulder about z).
fn waving_motion(file: &Path, n: usize) {
    let mut poses = vec![0.0f32; n * 165];
    for i in 0..n {
        // body_pose[15] is the left shoulder (joint 16), after the 3 of global_orient.
        poses[i * 165 + 3 + 15 * 3 + 2] =
            -0.8 * (i as f32 / n as f32 * std::f32::consts::TAU).sin();
    }
    common::write_beat2(file, n, poses);
}

/// `talkin export --motion` writes a GLB that reads back as the rig (55 named joints,
/// skinned mesh, unit weights on valid joints, inverse binds of the canonical pose) and
/// one animation of every joint's rotation and the root's translation.
#[test]
fn glb_holds_the_mesh_rig_and_animation() {
    let (dataset, run) = scene();
    let dir = common::temp_dir("export_glb");
    let (motion, out) = (dir.join("wave.npz"), dir.join("avatar.glb"));
    waving_motion(&motion, 12);
    let name = &dataset.subjects[0].name;
    let res = common::cli::talkin(&[
        "export",
        "--run",
        s(run),
        "--subject",
        name,
        "--out",
        s(&out),
        "--resolution",
        "32",
        "--motion",
        s(&motion),
    ]);
    assert!(res.status.success(), "{}", common::cli::stderr(&res));
    let bytes = std::fs::read(&out).unwrap();
    let gltf = gltf::Gltf::from_slice(&bytes).unwrap();
    let blob = gltf.blob.as_deref().unwrap();
    let skin = gltf.skins().next().unwrap();
    let joints: Vec<_> = skin.joints().collect();
    assert_eq!(joints.len(), talkin::human::body::N_JOINTS);
    assert_eq!(joints[15].name(), Some("head"));
    assert_eq!(joints[22].name(), Some("jaw"));
    let node = gltf.nodes().find(|n| n.mesh().is_some()).unwrap();
    assert_eq!(node.skin().unwrap().index(), skin.index());
    let primitive = node.mesh().unwrap().primitives().next().unwrap();
    let reader = primitive.reader(|_| Some(blob));
    let positions: Vec<[f32; 3]> = reader.read_positions().unwrap().collect();
    let joint_sets: Vec<[u16; 4]> = reader.read_joints(0).unwrap().into_u16().collect();
    let weights: Vec<[f32; 4]> = reader.read_weights(0).unwrap().into_f32().collect();
    let colours: Vec<[f32; 3]> = reader.read_colors(0).unwrap().into_rgb_f32().collect();
    assert!(positions.len() > 100);
    assert_eq!(joint_sets.len(), positions.len());
    assert_eq!(colours.len(), positions.len());
    for (j, w) in joint_sets.iter().zip(&weights) {
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6, "{w:?}");
        assert!(j.iter().all(|&j| (j as usize) < joints.len()));
    }
    // Some vertices are shared between joints: the learned weights blend.
    assert!(weights.iter().filter(|w| w[1] > 0.05).count() > positions.len() / 50);
    let ibm: Vec<[[f32; 4]; 4]> = skin
        .reader(|_| Some(blob))
        .read_inverse_bind_matrices()
        .unwrap()
        .collect();
    let model = &talkin::avatar::Avatar::load(run).unwrap();
    let canonical = &model.subject(name).unwrap().1.canonical;
    for j in [0, 16, 22, 30] {
        let joint = canonical.joint(j).as_vec3();
        let m = glam::Mat4::from_cols_array_2d(&ibm[j]);
        assert!(m.transform_point3(joint).length() < 1e-5, "joint {j}");
    }
    let animation = gltf.animations().next().unwrap();
    assert_eq!(animation.channels().count(), joints.len() + 1);
    let times: Vec<f32> = animation
        .channels()
        .next()
        .unwrap()
        .reader(|_| Some(blob))
        .read_inputs()
        .unwrap()
        .collect();
    assert_eq!(times.len(), 12);
    assert!((times[1] - 1.0 / 30.0).abs() < 1e-6, "{times:?}");
}

/// No such subject, a run without a checkpoint, a resolution out of range, an
/// unreadable motion: exit 1 naming the flag or file, and no file at --out.
#[test]
fn bad_input_exits_1_naming_the_flag_and_writes_nothing() {
    let (dataset, run) = scene();
    let dir = common::temp_dir("export_bad");
    let out = dir.join("never.glb");
    let empty_run = dir.join("no_checkpoint");
    std::fs::create_dir_all(&empty_run).unwrap();
    let garbage = dir.join("garbage.npz");
    std::fs::write(&garbage, b"not a zip").unwrap();
    let name = dataset.subjects[0].name.as_str();
    let check = |extra: &[&str], run: &Path, needles: &[&str]| {
        let mut args = vec!["export", "--run", s(run), "--out", s(&out)];
        args.extend_from_slice(extra);
        let res = common::cli::talkin(&args);
        let err = common::cli::stderr(&res);
        assert_eq!(res.status.code(), Some(1), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
        for n in needles {
            assert!(err.contains(n), "{args:?}: `{n}` not in: {err}");
        }
        assert!(!out.exists(), "{args:?} left a file");
        let left: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
        assert_eq!(left.len(), 2, "{args:?} left a partial file: {left:?}");
    };
    check(&["--subject", "zed"], run, &["--subject", "zed", name]);
    check(&["--subject", name], &empty_run, &[s(&empty_run)]);
    for r in ["8", "513"] {
        check(
            &["--subject", name, "--resolution", r],
            run,
            &["--resolution", r],
        );
    }
    check(
        &["--subject", name, "--motion", s(&garbage)],
        run,
        &["--motion", s(&garbage)],
    );
    let missing = dir.join("missing.npz");
    check(
        &["--subject", name, "--motion", s(&missing)],
        run,
        &["--motion", s(&missing)],
    );
}

/// Where `.ci/run` installs the npm packages `gltf-validator` and `three`
/// (`$TALKIN_NPM`, default `~/.cache/talkin-npm`; its `node_modules` is read).
fn npm_dir() -> PathBuf {
    std::env::var_os("TALKIN_NPM")
        .map(PathBuf::from)
        .or_else(|| dirs_home().map(|h| h.join(".cache/talkin-npm")))
        .expect("TALKIN_NPM or HOME")
}

fn dirs_home() -> Option<PathBuf> {
    std::env::var_os("HOME").map(PathBuf::from)
}

/// Serves `routes` (URL prefix -> file or directory) over HTTP/1.0 on a local port until
/// the process ends: what the page and its modules need, nothing else.
fn serve_files(routes: Vec<(&'static str, PathBuf)>) -> std::net::SocketAddr {
    use std::io::{BufRead, BufReader, Write};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            let mut line = String::new();
            let mut reader = BufReader::new(&stream);
            if reader.read_line(&mut line).is_err() {
                continue;
            }
            let path = line.split_whitespace().nth(1).unwrap_or("/").to_string();
            let path = path.split('?').next().unwrap_or("/");
            let file = routes.iter().find_map(|(prefix, target)| {
                let rest = path.strip_prefix(prefix)?;
                Some(if rest.is_empty() {
                    target.clone()
                } else {
                    target.join(rest.trim_start_matches('/'))
                })
            });
            let body = file.filter(|_| !path.contains("..")).and_then(|f| {
                let kind = match f.extension().and_then(|e| e.to_str()) {
                    Some("html") => "text/html",
                    Some("js") => "text/javascript",
                    Some("glb") => "model/gltf-binary",
                    _ => "application/octet-stream",
                };
                std::fs::read(f).ok().map(|b| (kind, b))
            });
            let mut stream = &stream;
            let _ = match body {
                Some((kind, bytes)) => write!(
                    stream,
                    "HTTP/1.0 200 OK\r\nContent-Type: {kind}\r\nContent-Length: {}\r\n\r\n",
                    bytes.len()
                )
                .and_then(|_| stream.write_all(&bytes)),
                None => write!(
                    stream,
                    "HTTP/1.0 404 Not Found\r\nContent-Length: 0\r\n\r\n"
                ),
            };
        }
    });
    addr
}

/// `cargo test --test export -- --ignored glb_in_validator_and_three`: exports the
/// test scene's avatar with a motion, runs the Khronos validator on it (`node`, npm
/// `gltf-validator`: no errors), then loads it with three.js's GLTFLoader in headless
/// Chromium (`chromium` or `$CHROMIUM`), which plays the animation and reports that the
/// skinned vertices moved; a screenshot of the start of the motion and a quarter of the way in is
/// written to the target tmp dir (`export_three.png`). The npm packages come from
/// [`npm_dir`].
#[test]
#[ignore = "needs node, the npm packages gltf-validator and three, and chromium"]
fn glb_in_validator_and_three() {
    let (dataset, run) = scene();
    let dir = common::temp_dir("export_three");
    let (motion, out) = (dir.join("wave.npz"), dir.join("avatar.glb"));
    waving_motion(&motion, 30);
    let res = common::cli::talkin(&[
        "export",
        "--run",
        s(run),
        "--subject",
        &dataset.subjects[0].name,
        "--out",
        s(&out),
        "--resolution",
        "48",
        "--motion",
        s(&motion),
    ]);
    assert!(res.status.success(), "{}", common::cli::stderr(&res));

    let modules = npm_dir().join("node_modules");
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let report = std::process::Command::new("node")
        .arg(repo.join("scripts/glb/validate.cjs"))
        .arg(&out)
        .env("NODE_PATH", &modules)
        .output()
        .expect("node runs");
    let text = String::from_utf8_lossy(&report.stdout);
    eprintln!("validator: {}", text.lines().take(6).collect::<String>());
    assert!(
        report.status.success() && text.contains("\"numErrors\": 0"),
        "{text}{}",
        String::from_utf8_lossy(&report.stderr)
    );

    let addr = serve_files(vec![
        ("/avatar.glb", out.clone()),
        ("/three", modules.join("three")),
        ("/", repo.join("scripts/glb/three_check.html")),
    ]);
    let profile = common::temp_dir("export_chromium_profile");
    let url = format!("http://{addr}/");
    let headless = |extra: &[&str]| {
        let flags = [
            // WebGL on the CPU.
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--virtual-time-budget=60000",
            "--window-size=800,600",
        ];
        common::browser::headless_chromium(&url, &profile, &[&flags[..], extra].concat())
    };
    let dom = headless(&["--dump-dom"]);
    let verdict = dom
        .split("data-verdict=\"")
        .nth(1)
        .and_then(|s| s.split('"').next())
        .unwrap_or_else(|| panic!("the page did not finish: {dom}"));
    eprintln!("three.js: {verdict}");
    assert!(verdict.starts_with("pass"), "{verdict}");
    let shot = Path::new(env!("CARGO_TARGET_TMPDIR")).join("export_three.png");
    headless(&[&format!("--screenshot={}", shot.display())]);
    assert!(std::fs::metadata(&shot).unwrap().len() > 0);
    eprintln!("screenshot {}", shot.display());
}

/// `TALKIN_EXPORT_RUN=RUN TALKIN_EXPORT_DATA=DATA cargo test --release --test export --
/// --ignored same_avatar_on_a_run --nocapture`: the same comparison as
/// `posed_mesh_matches_the_render_on_held_out_frames` on a run of your own (e.g. the
/// demo's), every subject, the first four test_same frames of each, at the default
/// resolution (`TALKIN_EXPORT_RESOLUTION` for another); prints each frame's IoU and PSNR
/// and their means.
#[test]
#[ignore = "needs a trained run: TALKIN_EXPORT_RUN and TALKIN_EXPORT_DATA"]
fn same_avatar_on_a_run() {
    let var = |k: &str| std::env::var(k).unwrap_or_else(|_| panic!("set {k}"));
    let run = PathBuf::from(var("TALKIN_EXPORT_RUN"));
    let dataset = Dataset::load(Path::new(&var("TALKIN_EXPORT_DATA"))).unwrap();
    let resolution = std::env::var("TALKIN_EXPORT_RESOLUTION")
        .map_or(talkin::export::DEFAULT_RESOLUTION, |r| r.parse().unwrap());
    let avatar = Avatar::load(&run).unwrap();
    let frames = split_frames(&dataset, Split::TestSame).unwrap();
    let mut all = Vec::new();
    for (s, subject) in dataset.subjects.iter().enumerate() {
        let opts = SurfaceOptions {
            resolution,
            ..SurfaceOptions::default()
        };
        let exported = export_avatar(&avatar, &subject.name, &opts).unwrap();
        let mine: Vec<usize> = frames
            .iter()
            .copied()
            .filter(|&i| dataset.frames[i].subject == s)
            .take(4)
            .collect();
        for (i, (iou, psnr)) in mine
            .iter()
            .zip(same_avatar_scores(&avatar, &dataset, &exported, &mine))
        {
            eprintln!(
                "{} frame {i}: IoU {iou:.3}, person-box PSNR {psnr:.2} dB",
                subject.name
            );
            all.push((iou, psnr));
        }
    }
    let n = all.len() as f64;
    let (iou, psnr) = all
        .iter()
        .fold((0.0, 0.0), |(a, b), (i, p)| (a + i / n, b + p / n));
    eprintln!("mean over {n} frames: IoU {iou:.3}, PSNR {psnr:.2} dB");
}
