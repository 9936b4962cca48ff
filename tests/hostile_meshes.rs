//! Hostile glTF documents against the character-mesh reader (`parse_gltf`): one crafted
//! document per finding of the audit (each a panic, an abort, an endless read, a hang or
//! a silent loss before), built here as JSON text or GLB bytes, each refused with an
//! error naming the object and the value, within a small allocation measured by
//! `alloc_meter`; properties over valid minimal documents (as `.gltf` with a data URI or
//! as GLB) with up to three header values changed to anything (accessor count, byte
//! offset, component type and type; buffer view offset, length and stride; buffer length;
//! sparse counts and offsets; indices; joints), over plausible documents with arbitrary
//! index values, and over documents with bytes of their JSON replaced, each read without
//! a panic under 1 MiB and within the meter's bounds (unchanged, to exactly what the
//! document holds); and the real assets read exactly as the `gltf` crate reads them
//! (skipped, with the reason printed, when the shared data is absent).

mod common;

mod alloc_meter;

use alloc_meter::{measure, Usage};
use glam::{DMat4, DVec3};
use proptest::prelude::*;
use proptest::test_runner::Config;
use rigless::character::mesh::{
    parse_gltf, read_gltf, AccessorProblem, BufferProblem, GlbProblem, MeshData, MeshError,
    NodeProblem, PrimitiveProblem, SkinProblem, MAX_SKIN_JOINTS,
};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// What a refused document may allocate at its peak: 1 MiB (the JSON's objects, the
/// error's text).
const REFUSED: usize = 1 << 20;

/// Standard base64 with padding.
fn base64(bytes: &[u8]) -> String {
    const ABC: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for c in bytes.chunks(3) {
        let n = (u32::from(c[0]) << 16)
            | (u32::from(*c.get(1).unwrap_or(&0)) << 8)
            | u32::from(*c.get(2).unwrap_or(&0));
        for k in 0..4 {
            if k <= c.len() {
                out.push(ABC[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// A `data:` URI holding `bytes`.
fn data_uri(bytes: &[u8]) -> String {
    format!("data:application/octet-stream;base64,{}", base64(bytes))
}

/// A GLB container: the JSON chunk (padded with spaces) and, when given, a BIN chunk
/// (padded with zeros).
fn glb(json: &str, bin: Option<&[u8]>) -> Vec<u8> {
    let mut j = json.as_bytes().to_vec();
    while !j.len().is_multiple_of(4) {
        j.push(b' ');
    }
    let mut chunks = Vec::new();
    chunks.extend((j.len() as u32).to_le_bytes());
    chunks.extend(b"JSON");
    chunks.extend(&j);
    if let Some(bin) = bin {
        let mut b = bin.to_vec();
        while !b.len().is_multiple_of(4) {
            b.push(0);
        }
        chunks.extend((b.len() as u32).to_le_bytes());
        chunks.extend(b"BIN\0");
        chunks.extend(&b);
    }
    let mut out = b"glTF".to_vec();
    out.extend(2u32.to_le_bytes());
    out.extend((12 + chunks.len() as u32).to_le_bytes());
    out.extend(chunks);
    out
}

/// Little-endian floats.
fn floats(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// One triangle's positions (the unit right triangle in the XY plane).
fn triangle_bytes() -> Vec<u8> {
    floats(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0])
}

/// A POSITION accessor: VEC3 of floats, `count` of them from `view`, with min and max.
fn positions(view: usize, count: u64) -> Value {
    json!({"bufferView": view, "componentType": 5126, "count": count, "type": "VEC3",
           "min": [0, 0, 0], "max": [1, 1, 0]})
}

/// Parses `bytes` (no folder) under the meter.
fn parse(bytes: &[u8]) -> (Result<MeshData, MeshError>, Usage) {
    measure(|| parse_gltf(bytes, None))
}

/// Parses `bytes`, expects an error, checks the allocation of a refused document and
/// returns the error.
fn refused(bytes: &[u8]) -> MeshError {
    let (r, u) = parse(bytes);
    let e = r.expect_err("the document is refused");
    assert!(u.peak < REFUSED, "{e}: {u:?}");
    e
}

#[test]
fn finding_1_an_accessor_index_past_the_end_is_named_not_a_panic() {
    // Before: gltf-json's primitive_validate_hook indexed `root.accessors[5]` unchecked.
    let doc =
        r#"{"asset":{"version":"2.0"},"meshes":[{"primitives":[{"attributes":{"POSITION":5}}]}]}"#;
    let e = refused(doc.as_bytes());
    match &e {
        MeshError::Reference {
            field,
            index,
            array,
            count,
        } => {
            assert_eq!(field, "meshes[0].primitives[0].attributes.POSITION");
            assert_eq!((*index, *array, *count), (5, "accessors", 0));
        }
        other => panic!("{other}"),
    }
    assert_eq!(
        e.to_string(),
        "glTF meshes[0].primitives[0].attributes.POSITION is 5, but the document has 0 accessors"
    );
    // The same in a GLB, and through the other references the validation would follow.
    assert!(matches!(
        refused(&glb(doc, None)),
        MeshError::Reference { index: 5, .. }
    ));
    let more = [
        (
            r#"{"asset":{"version":"2.0"},"bufferViews":[{"buffer":3,"byteLength":4}]}"#,
            "bufferViews[0].buffer",
        ),
        (
            r#"{"asset":{"version":"2.0"},"accessors":[{"bufferView":9,"componentType":5126,"count":1,"type":"VEC3"}]}"#,
            "accessors[0].bufferView",
        ),
        (
            r#"{"asset":{"version":"2.0"},"nodes":[{"children":[7]}]}"#,
            "nodes[0].children[0]",
        ),
        (
            r#"{"asset":{"version":"2.0"},"nodes":[{"mesh":0}]}"#,
            "nodes[0].mesh",
        ),
        (
            r#"{"asset":{"version":"2.0"},"skins":[{"joints":[0]}]}"#,
            "skins[0].joints[0]",
        ),
    ];
    for (doc, at) in more {
        match refused(doc.as_bytes()) {
            MeshError::Reference { field, .. } => assert_eq!(field, at),
            other => panic!("{doc}: {other}"),
        }
    }
}

#[test]
fn finding_2_a_uri_that_decodes_to_non_utf8_is_an_error() {
    // Before: `urlencoding::decode(uri).unwrap()` in the crate's import panicked.
    let doc = r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":1,"uri":"%FF"}]}"#;
    let dir = tempfile::tempdir().unwrap();
    for base in [None, Some(dir.path())] {
        let (r, u) = measure(|| parse_gltf(doc.as_bytes(), base));
        match r {
            Err(MeshError::Buffer {
                buffer: 0,
                problem: BufferProblem::PercentEncoding { uri },
            }) => assert_eq!(uri, "%FF"),
            other => panic!("{other:?}"),
        }
        assert!(u.peak < REFUSED, "{u:?}");
    }
    // A bad escape too; a good one names the file it decodes to.
    let bad = r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":1,"uri":"a%2"}]}"#;
    assert!(matches!(
        refused(bad.as_bytes()),
        MeshError::Buffer {
            problem: BufferProblem::PercentEncoding { .. },
            ..
        }
    ));
    let good =
        r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":1,"uri":"my%20buffer.bin"}]}"#;
    match parse_gltf(good.as_bytes(), Some(dir.path())) {
        Err(MeshError::Buffer {
            problem: BufferProblem::Io { path, .. },
            ..
        }) => assert!(path.ends_with("my buffer.bin"), "{path}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn finding_3_a_stride_smaller_than_the_element_is_an_error() {
    // Before: the accessor iterator panicked (positions, and inverse bind matrices).
    let doc = r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":12,"uri":"data:;base64,AAAAAAAAAAAAAAAA"}],"bufferViews":[{"buffer":0,"byteLength":12,"byteStride":4}],"accessors":[{"bufferView":0,"componentType":5126,"count":1,"type":"VEC3","min":[0,0,0],"max":[0,0,0]}],"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],"nodes":[{"mesh":0}]}"#;
    let e = refused(doc.as_bytes());
    assert!(
        matches!(
            e,
            MeshError::Accessor {
                accessor: 0,
                problem: AccessorProblem::StrideTooSmall {
                    view: 0,
                    stride: 4,
                    element: 12
                }
            }
        ),
        "{e}"
    );
    assert_eq!(
        e.to_string(),
        "glTF accessors[0]: bufferViews[0].byteStride 4 is smaller than its 12-byte elements"
    );
    // A skin's inverse bind matrices (MAT4, 64 bytes) in a view of stride 4.
    let mut bin = triangle_bytes();
    bin.extend(floats(&DMat4::IDENTITY.to_cols_array().map(|v| v as f32)));
    let doc = json!({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": [{"buffer": 0, "byteLength": 36},
                        {"buffer": 0, "byteOffset": 36, "byteLength": 64, "byteStride": 4}],
        "accessors": [positions(0, 3),
                      {"bufferView": 1, "componentType": 5126, "count": 1, "type": "MAT4"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "skins": [{"joints": [1], "inverseBindMatrices": 1}],
        "nodes": [{"mesh": 0, "skin": 0}, {"name": "root"}]
    });
    let e = refused(&glb(&doc.to_string(), Some(&bin)));
    assert!(
        matches!(
            e,
            MeshError::Accessor {
                accessor: 1,
                problem: AccessorProblem::StrideTooSmall {
                    view: 1,
                    stride: 4,
                    element: 64
                }
            }
        ),
        "{e}"
    );
}

#[test]
fn finding_4_float_or_signed_indices_are_an_error_naming_the_primitive() {
    // Before: `unreachable!()` in the crate's read_indices.
    for component_type in [5126u32, 5120, 5122] {
        let doc = format!(
            r#"{{"asset":{{"version":"2.0"}},"buffers":[{{"byteLength":36,"uri":"data:;base64,AAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAA"}}],"bufferViews":[{{"buffer":0,"byteLength":36}}],"accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[0,0,0]}},{{"bufferView":0,"componentType":{component_type},"count":3,"type":"SCALAR"}}],"meshes":[{{"name":"body","primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],"nodes":[{{"mesh":0}}]}}"#
        );
        let e = refused(doc.as_bytes());
        match &e {
            MeshError::Primitive { at, problem } => {
                assert_eq!((at.mesh, at.primitive), (0, 0));
                assert_eq!(
                    *problem,
                    PrimitiveProblem::IndexFormat {
                        accessor: 1,
                        accessor_type: "SCALAR",
                        component_type
                    }
                );
            }
            other => panic!("{other}"),
        }
        assert!(
            e.to_string().starts_with(&format!(
                "glTF meshes[0] \"body\" primitives[0]: indices accessors[1] is SCALAR of componentType {component_type}"
            )),
            "{e}"
        );
    }
}

#[test]
fn finding_5_sparse_counts_and_offsets_are_bounded() {
    // Before: a view-less sparse accessor of count 4e9 made Vec::extend reserve 96 GB.
    let doc = r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":16,"uri":"data:;base64,AAAAAAAAAAAAAAAAAAAAAA=="}],"bufferViews":[{"buffer":0,"byteLength":16}],"accessors":[{"componentType":5126,"count":4000000000,"type":"VEC3","min":[0,0,0],"max":[0,0,0],"sparse":{"count":1,"indices":{"bufferView":0,"componentType":5125},"values":{"bufferView":0,"byteOffset":4}}}],"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],"nodes":[{"mesh":0}]}"#;
    let e = refused(doc.as_bytes());
    assert!(
        matches!(
            e,
            MeshError::Accessor {
                accessor: 0,
                problem: AccessorProblem::TooLarge {
                    count: 4_000_000_000,
                    element: 12,
                    limit: 16
                }
            }
        ),
        "{e}"
    );
    // The other numbers of a sparse accessor, and offsets whose sum overflows 64 bits.
    let with = |accessor: Value, view: Value| {
        json!({
            "asset": {"version": "2.0"},
            "buffers": [{"byteLength": 48, "uri": data_uri(&[0; 48])}],
            "bufferViews": [view],
            "accessors": [accessor],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "nodes": [{"mesh": 0}]
        })
        .to_string()
    };
    let view = json!({"buffer": 0, "byteLength": 48});
    let sparse = |count: u64, values_offset: u64| {
        json!({"componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [0, 0, 0],
               "sparse": {"count": count, "indices": {"bufferView": 0, "componentType": 5125},
                          "values": {"bufferView": 0, "byteOffset": values_offset}}})
    };
    let cases: Vec<(String, AccessorProblem)> = vec![
        (
            with(sparse(4, 0), view.clone()),
            AccessorProblem::SparseCount {
                sparse: 4,
                count: 3,
            },
        ),
        (
            with(sparse(2, u64::MAX), view.clone()),
            AccessorProblem::SparseOutsideView {
                part: "values",
                view: 0,
                offset: u64::MAX,
                count: 2,
                size: 12,
                view_length: 48,
            },
        ),
        (
            with(
                json!({"bufferView": 0, "byteOffset": u64::MAX - 3, "componentType": 5126,
                       "count": u64::MAX, "type": "VEC3", "min": [0, 0, 0], "max": [0, 0, 0]}),
                view.clone(),
            ),
            AccessorProblem::OutsideView {
                view: 0,
                offset: u64::MAX - 3,
                stride: 12,
                count: u64::MAX,
                element: 12,
                view_length: 48,
            },
        ),
    ];
    for (doc, problem) in cases {
        match refused(doc.as_bytes()) {
            MeshError::Accessor {
                accessor: 0,
                problem: p,
            } => assert_eq!(p, problem),
            other => panic!("{other}"),
        }
    }
    // A view whose offset and length overflow when added.
    let doc = with(
        positions(0, 3),
        json!({"buffer": 0, "byteOffset": u64::MAX, "byteLength": u64::MAX}),
    );
    assert!(matches!(
        refused(doc.as_bytes()),
        MeshError::ViewOutsideBuffer {
            view: 0,
            offset: u64::MAX,
            length: u64::MAX,
            buffer_length: 48,
            ..
        }
    ));
    // Count 0 of a sparse accessor substitutes nothing (the crate underflowed on it).
    let doc = with(sparse(0, 0), view);
    match parse(doc.as_bytes()).0 {
        Ok(m) => assert_eq!(m.positions, vec![DVec3::ZERO; 3]),
        Err(e) => panic!("{e}"),
    }
}

#[test]
fn a_sparse_accessor_within_its_bounds_is_read() {
    // Three zero positions from no view, two replaced: indices [1, 2] (u16), values (and
    // 8 bytes more, so the buffers hold the 36 bytes of the accessor's zeros).
    let mut bin = Vec::new();
    bin.extend(1u16.to_le_bytes());
    bin.extend(2u16.to_le_bytes());
    bin.extend(floats(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0]));
    bin.extend([0; 8]);
    let doc = json!({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": [{"buffer": 0, "byteLength": 4}, {"buffer": 0, "byteOffset": 4, "byteLength": 24}],
        "accessors": [{"componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0],
                       "sparse": {"count": 2, "indices": {"bufferView": 0, "componentType": 5123},
                                  "values": {"bufferView": 1}}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0, "translation": [0, 0, 5]}]
    });
    let m = parse_gltf(&glb(&doc.to_string(), Some(&bin)), None).unwrap();
    assert_eq!(
        m.positions,
        vec![
            DVec3::new(0.0, 0.0, 5.0),
            DVec3::new(1.0, 0.0, 5.0),
            DVec3::new(0.0, 1.0, 5.0)
        ]
    );
    assert_eq!(m.triangles, vec![[0, 1, 2]]);
    // A sparse index past the accessor's count is named.
    let mut bad = bin.clone();
    bad[2] = 3;
    match parse_gltf(&glb(&doc.to_string(), Some(&bad)), None) {
        Err(MeshError::Accessor {
            accessor: 0,
            problem:
                AccessorProblem::SparseIndex {
                    entry: 1,
                    index: 3,
                    count: 3,
                },
        }) => {}
        other => panic!("{other:?}"),
    }
}

#[test]
fn finding_6_buffer_files_are_regular_files_of_their_length() {
    // Before: "file:///dev/zero" was read to the end, forever.
    let doc =
        r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":1,"uri":"file:///dev/zero"}]}"#;
    let dir = tempfile::tempdir().unwrap();
    for base in [None, Some(dir.path())] {
        let (r, u) = measure(|| parse_gltf(doc.as_bytes(), base));
        match r {
            Err(MeshError::Buffer {
                buffer: 0,
                problem: BufferProblem::Scheme { uri },
            }) => assert_eq!(uri, "file:///dev/zero"),
            other => panic!("{other:?}"),
        }
        assert!(u.peak < REFUSED, "{u:?}");
    }
    // Relative paths: a link to /dev/zero, a pipe (opening it would wait for a writer),
    // an absolute path, a file of the wrong length, then the right one.
    let with_uri = |uri: &str, len: usize| {
        json!({
            "asset": {"version": "2.0"},
            "buffers": [{"byteLength": len, "uri": uri}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}],
            "accessors": [positions(0, 3)],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "nodes": [{"mesh": 0}]
        })
        .to_string()
    };
    std::os::unix::fs::symlink("/dev/zero", dir.path().join("zero.bin")).unwrap();
    let fifo = dir.path().join("pipe.bin");
    let c = std::ffi::CString::new(fifo.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: a NUL-terminated path; mkfifo only creates the node.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    // A link to /dev/zero leads out of the folder (refused before it is looked at); a
    // pipe in the folder is not a regular file.
    for name in ["zero.bin", "pipe.bin"] {
        let (r, u) = measure(|| parse_gltf(with_uri(name, 36).as_bytes(), Some(dir.path())));
        match r {
            Err(MeshError::Buffer {
                problem: BufferProblem::LinkOutsideFolder { uri },
                ..
            }) => assert_eq!((name, uri.as_str()), ("zero.bin", name)),
            Err(MeshError::Buffer {
                problem: BufferProblem::NotAFile { path },
                ..
            }) => assert!(name == "pipe.bin" && path.ends_with(name), "{path}"),
            other => panic!("{name}: {other:?}"),
        }
        assert!(u.peak < REFUSED, "{u:?}");
    }
    let e = parse_gltf(with_uri("/etc/hostname", 36).as_bytes(), Some(dir.path()));
    assert!(
        matches!(
            e,
            Err(MeshError::Buffer {
                problem: BufferProblem::Absolute { .. },
                ..
            })
        ),
        "{e:?}"
    );
    let mut content = triangle_bytes();
    content.extend([0; 100]);
    std::fs::write(dir.path().join("tri.bin"), &content).unwrap();
    let (r, u) = measure(|| parse_gltf(with_uri("tri.bin", 36).as_bytes(), Some(dir.path())));
    match r {
        Err(MeshError::Buffer {
            problem:
                BufferProblem::FileLength {
                    declared: 36,
                    actual: 136,
                    ..
                },
            ..
        }) => {}
        other => panic!("{other:?}"),
    }
    assert!(u.peak < REFUSED, "{u:?}");
    std::fs::write(dir.path().join("tri.bin"), triangle_bytes()).unwrap();
    let m = parse_gltf(with_uri("tri.bin", 36).as_bytes(), Some(dir.path())).unwrap();
    assert_eq!(m.triangles, vec![[0, 1, 2]]);
    // Without a folder, a file cannot be read.
    assert!(matches!(
        parse_gltf(with_uri("tri.bin", 36).as_bytes(), None),
        Err(MeshError::Buffer {
            problem: BufferProblem::NoFolder { .. },
            ..
        })
    ));
    // read_gltf reads it from the document's folder.
    let path = dir.path().join("tri.gltf");
    std::fs::write(&path, with_uri("tri.bin", 36)).unwrap();
    assert_eq!(read_gltf(&path).unwrap().triangles, vec![[0, 1, 2]]);
}

/// A document of one triangle whose positions are buffer 0, read from `uri`.
fn triangle_at(uri: &str) -> String {
    json!({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": 36, "uri": uri}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [positions(0, 3)],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0}]
    })
    .to_string()
}

/// A buffer URI reaches only files in the document's folder and below, however the way
/// out is spelled. A 36-byte file beside the folder (readable as a triangle, so any of
/// these URIs loaded it before) is refused by every spelling of `..`, and through
/// symbolic links leading out (to the file, or to the folder above); links that stay
/// inside, backslashes and `.` components inside are read.
#[test]
fn buffer_uris_reach_only_the_documents_folder() {
    use std::os::unix::fs::symlink;
    let root = tempfile::tempdir().unwrap();
    let folder = root.path().join("mesh");
    std::fs::create_dir_all(folder.join("sub")).unwrap();
    std::fs::write(root.path().join("secret.bin"), triangle_bytes()).unwrap();
    std::fs::write(folder.join("sub/tri.bin"), triangle_bytes()).unwrap();
    symlink(root.path().join("secret.bin"), folder.join("out.bin")).unwrap();
    symlink("..", folder.join("up")).unwrap();
    symlink("sub/tri.bin", folder.join("in.bin")).unwrap();
    symlink(folder.join("sub"), folder.join("sub/again")).unwrap();
    let read = |uri: &str| parse_gltf(triangle_at(uri).as_bytes(), Some(&folder));
    for uri in [
        "../secret.bin".to_string(),
        "../../../../../../../../../../../..".to_string()
            + &root.path().display().to_string()
            + "/secret.bin",
        "%2e%2e/secret.bin".into(),
        "%2E%2e/secret.bin".into(),
        "%2e%2E%2Fsecret.bin".into(),
        "..\\secret.bin".into(),
        "..%5Csecret.bin".into(),
        "sub/../../secret.bin".into(),
        "sub\\..\\..\\secret.bin".into(),
    ] {
        match read(&uri) {
            Err(MeshError::Buffer {
                buffer: 0,
                problem: BufferProblem::OutsideFolder { uri: named },
            }) => assert!(uri.starts_with(named.trim_end_matches("...")), "{named}"),
            other => panic!("{uri}: {other:?}"),
        }
    }
    for uri in ["out.bin", "up/secret.bin", "up/mesh/../secret.bin"] {
        match read(uri) {
            Err(MeshError::Buffer {
                buffer: 0,
                problem: BufferProblem::LinkOutsideFolder { uri: named },
            }) => assert_eq!(named, uri),
            other => panic!("{uri}: {other:?}"),
        }
    }
    match read("sub/tri.bin%00.png") {
        Err(MeshError::Buffer {
            problem: BufferProblem::NulByte { uri },
            ..
        }) => assert_eq!(uri, "sub/tri.bin%00.png"),
        other => panic!("{other:?}"),
    }
    for uri in [
        "in.bin",
        "sub\\tri.bin",
        "./sub/./x/../tri.bin",
        "sub/again/tri.bin",
        "up/mesh/sub/tri.bin",
    ] {
        let m = read(uri).unwrap_or_else(|e| panic!("{uri}: {e}"));
        assert_eq!(m.triangles, vec![[0, 1, 2]], "{uri}");
        assert_eq!(m.positions[1], DVec3::X, "{uri}");
    }
}

/// A buffer file of the wrong length, or whose bytes make no triangle, is named by its
/// path and its numbers, never by what it holds: a 40-byte text file read as the
/// positions buffer, and the same text where indices were expected.
#[test]
fn buffer_errors_never_echo_the_files_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let text = b"root:x:0:0:root:/root:/bin/bash\nAAAAAAAA";
    std::fs::write(dir.path().join("words.bin"), text).unwrap();
    let e = parse_gltf(triangle_at("words.bin").as_bytes(), Some(dir.path()))
        .expect_err("40 bytes for 36")
        .to_string();
    assert!(
        e.contains("words.bin has 40 bytes, but byteLength is 36"),
        "{e}"
    );
    let doc = json!({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": 36, "uri": data_uri(&triangle_bytes())},
                    {"byteLength": 40, "uri": "words.bin"}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}, {"buffer": 1, "byteLength": 36}],
        "accessors": [positions(0, 3), {"bufferView": 1, "componentType": 5125, "count": 9, "type": "SCALAR"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "nodes": [{"mesh": 0}]
    })
    .to_string();
    let e = parse_gltf(doc.as_bytes(), Some(dir.path()))
        .expect_err("indices of text")
        .to_string();
    for word in ["root", "bash", "AAAA", "/bin"] {
        assert!(!e.contains(word), "{word} in {e}");
    }
    // The first index is the text's first four bytes, as a number: "root" read as u32.
    assert!(e.contains(&u32::from_le_bytes(*b"root").to_string()), "{e}");
}

/// A document with one triangle (nodes[0]) skinned by a skin of `joints` (node indices
/// into a chain of `chain` bone nodes after it, nodes[1] the root).
fn skinned_doc(joints: &[usize], chain: usize) -> Value {
    let mut nodes = vec![json!({"mesh": 0, "skin": 0})];
    for k in 0..chain {
        let mut n = json!({"name": format!("bone{k}")});
        if k + 1 < chain {
            n["children"] = json!([k + 2]);
        }
        nodes.push(n);
    }
    json!({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [positions(0, 3)],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "skins": [{"joints": joints}],
        "nodes": nodes
    })
}

/// [`skinned_doc`] as a GLB with the triangle in its BIN chunk.
fn skinned(joints: &[usize], chain: usize) -> Vec<u8> {
    glb(
        &skinned_doc(joints, chain).to_string(),
        Some(&triangle_bytes()),
    )
}

#[test]
fn finding_7_a_skin_of_millions_of_joints_is_refused_at_once() {
    // Before: two million repeats of one joint hung the quadratic joint loops.
    let bytes = skinned(&vec![1; 2_000_000], 1);
    let t0 = Instant::now();
    let (r, u) = parse(&bytes);
    assert!(t0.elapsed() < Duration::from_secs(5), "{:?}", t0.elapsed());
    match r {
        Err(MeshError::Skin {
            skin: 0,
            problem: SkinProblem::TooManyJoints { joints, max },
        }) => assert_eq!((joints, max), (2_000_000, MAX_SKIN_JOINTS)),
        other => panic!("{other:?}"),
    }
    eprintln!("2,000,000 joints: {} bytes, {u:?}", bytes.len());
    // The joints' indices are 4 bytes each in the crate's types, for 2 bytes of JSON
    // each: 2 bytes per byte, up to twice that while their vector grows.
    assert!(u.peak < 4 * bytes.len() + REFUSED, "{u:?}");
    // A joint twice, and a cycle of children.
    match parse(&skinned(&[1, 2, 1], 3)).0 {
        Err(MeshError::Skin {
            problem: SkinProblem::DuplicateJoint { node: 1 },
            ..
        }) => {}
        other => panic!("{other:?}"),
    }
    let cycle = r#"{"asset":{"version":"2.0"},"nodes":[{"children":[1]},{"children":[2]},{"children":[1]}]}"#;
    match refused(cycle.as_bytes()) {
        MeshError::Node {
            node: 1,
            problem:
                NodeProblem::TwoParents {
                    first: 0,
                    second: 2,
                },
        } => {}
        other => panic!("{other}"),
    }
    let cycle = r#"{"asset":{"version":"2.0"},"nodes":[{"children":[1]},{"children":[0]}]}"#;
    match refused(cycle.as_bytes()) {
        MeshError::Node {
            problem: NodeProblem::Cycle,
            ..
        } => {}
        other => panic!("{other}"),
    }
    // A skin of 1,024 joints spread over a ring of 200,000 nodes: before, ordering the
    // joints by depth walked the ring for every joint at every comparison (5.6 s here,
    // growing with the ring), to return joints whose parents make a cycle.
    let n = 200_000usize;
    let mut ring = skinned_doc(
        &(0..1024).map(|k| 1 + k * (n / 1024)).collect::<Vec<_>>(),
        0,
    );
    let nodes = ring["nodes"].as_array_mut().unwrap();
    nodes.extend((0..n).map(|k| json!({"children": [if k + 1 < n { k + 2 } else { 1 }]})));
    let bytes = glb(&ring.to_string(), Some(&triangle_bytes()));
    let t0 = Instant::now();
    let (e, u) = parse(&bytes);
    assert!(t0.elapsed() < Duration::from_secs(5), "{:?}", t0.elapsed());
    eprintln!("ring of 200,000 nodes: {} bytes, {u:?}", bytes.len());
    u.assert_within(bytes.len(), "ring");
    assert!(
        matches!(
            e,
            Err(MeshError::Node {
                problem: NodeProblem::Cycle,
                ..
            })
        ),
        "{e:?}"
    );
    // The most joints allowed, a chain 1,024 deep listed leaf first, read at once with
    // each joint's parent the one above it.
    let joints: Vec<usize> = (1..=MAX_SKIN_JOINTS).rev().collect();
    let t0 = Instant::now();
    let m = parse_gltf(&skinned(&joints, MAX_SKIN_JOINTS), None).unwrap();
    assert!(t0.elapsed() < Duration::from_secs(5), "{:?}", t0.elapsed());
    assert_eq!(m.skin_joints.len(), MAX_SKIN_JOINTS);
    assert_eq!(m.skin_joints[0].name, "bone0");
    assert_eq!(m.skin_joints[0].parent, None);
    for (k, j) in m.skin_joints.iter().enumerate().skip(1) {
        assert_eq!(
            (j.name.clone(), j.parent),
            (format!("bone{k}"), Some(k - 1))
        );
    }
    let too_many: Vec<usize> = (1..=MAX_SKIN_JOINTS + 1).collect();
    assert!(matches!(
        parse(&skinned(&too_many, MAX_SKIN_JOINTS + 1)).0,
        Err(MeshError::Skin {
            problem: SkinProblem::TooManyJoints { joints: 1025, .. },
            ..
        })
    ));
}

#[test]
fn finding_8_indices_not_in_threes_are_an_error_naming_the_primitive() {
    // Before: `chunks_exact(3)` dropped the last index silently.
    let mut bin = triangle_bytes();
    bin.extend([0u8, 1, 2, 0]);
    let doc = |indices: bool, vertices: u64| {
        let mut prim = json!({"attributes": {"POSITION": 0}});
        if indices {
            prim["indices"] = json!(1);
        }
        json!({
            "asset": {"version": "2.0"},
            "buffers": [{"byteLength": 40}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 4}],
            "accessors": [positions(0, vertices),
                          {"bufferView": 1, "componentType": 5121, "count": 4, "type": "SCALAR"}],
            "meshes": [{"name": "hand", "primitives": [{"attributes": {"POSITION": 0}, "indices": 1}, prim]}],
            "nodes": [{"mesh": 0}]
        })
        .to_string()
    };
    let e = refused(&glb(&doc(true, 3), Some(&bin)));
    match &e {
        MeshError::Primitive { at, problem } => {
            assert_eq!(
                (at.mesh, at.name.as_deref(), at.primitive),
                (0, Some("hand"), 0)
            );
            assert_eq!(
                *problem,
                PrimitiveProblem::NotTriangles {
                    count: 4,
                    indexed: true
                }
            );
        }
        other => panic!("{other}"),
    }
    assert_eq!(
        e.to_string(),
        "glTF meshes[0] \"hand\" primitives[0]: 4 indices, not a multiple of 3 (a triangle list)"
    );
    // Without indices, the vertices are the triangle list: 2 of them are not.
    let mut doc2: Value = serde_json::from_str(&doc(false, 2)).unwrap();
    doc2["meshes"][0]["primitives"] = json!([{"attributes": {"POSITION": 0}}]);
    match refused(&glb(&doc2.to_string(), Some(&bin))) {
        MeshError::Primitive { problem, .. } => assert_eq!(
            problem,
            PrimitiveProblem::NotTriangles {
                count: 2,
                indexed: false
            }
        ),
        other => panic!("{other}"),
    }
}

#[test]
fn a_million_empty_nodes_are_refused_before_they_are_built() {
    // 3 MB of `{}` would take 224 MB as the crate's nodes (and twice that while growing).
    let mut doc = String::from(r#"{"asset":{"version":"2.0"},"nodes":["#);
    doc.push_str(&vec!["{}"; 1_000_000].join(","));
    doc.push_str("]}");
    let e = refused(doc.as_bytes());
    match &e {
        MeshError::TooManyObjects { objects, .. } => assert_eq!(*objects, 1_000_000),
        other => panic!("{other}"),
    }
}

#[test]
fn instanced_meshes_are_bounded_by_the_input() {
    // One mesh of 30,000 vertices (360 KB) drawn by 20 nodes: 600,000 vertices out of
    // under 400 KB of GLB, over the budget of 65,536 plus one per 4 bytes.
    let n = 30_000u64;
    let bin = vec![0u8; 12 * n as usize];
    let doc = json!({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": [{"buffer": 0, "byteLength": bin.len()}],
        "accessors": [positions(0, n)],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": vec![json!({"mesh": 0}); 20]
    });
    let bytes = glb(&doc.to_string(), Some(&bin));
    let (r, u) = parse(&bytes);
    match r {
        Err(MeshError::Primitive {
            problem:
                PrimitiveProblem::OverBudget {
                    what: "vertices",
                    total,
                    budget,
                    ..
                },
            ..
        }) => {
            assert_eq!(budget, 65_536 + bytes.len() as u64 / 4);
            assert!(total > budget && total <= budget + n, "{total}");
        }
        other => panic!("{other:?}"),
    }
    assert!(u.peak < REFUSED, "{u:?}");
}

#[test]
fn glb_containers_that_do_not_fit_are_named() {
    let good = glb(r#"{"asset":{"version":"2.0"}}"#, None);
    let with = |edit: &dyn Fn(&mut Vec<u8>)| {
        let mut b = good.clone();
        edit(&mut b);
        b
    };
    let cases: Vec<(Vec<u8>, GlbProblem)> = vec![
        (b"glTF".to_vec(), GlbProblem::TooShort { length: 4 }),
        (with(&|b| b[4] = 1), GlbProblem::Version { version: 1 }),
        (
            with(&|b| b[8..12].copy_from_slice(&4u32.to_le_bytes())),
            GlbProblem::Length {
                declared: 4,
                actual: good.len(),
            },
        ),
        (
            with(&|b| b[8..12].copy_from_slice(&u32::MAX.to_le_bytes())),
            GlbProblem::Length {
                declared: u32::MAX,
                actual: good.len(),
            },
        ),
        (
            with(&|b| b[12..16].copy_from_slice(&u32::MAX.to_le_bytes())),
            GlbProblem::Chunk {
                offset: 12,
                length: u32::MAX.into(),
                remaining: good.len() - 20,
            },
        ),
        (
            with(&|b| b[16..20].copy_from_slice(b"BIN\0")),
            GlbProblem::FirstChunk {
                chunk_type: u32::from_le_bytes(*b"BIN\0"),
            },
        ),
        (
            with(&|b| {
                b.truncate(12);
                b[8..12].copy_from_slice(&12u32.to_le_bytes());
            }),
            GlbProblem::NoJson,
        ),
    ];
    for (bytes, problem) in cases {
        match refused(&bytes) {
            MeshError::Glb { problem: p } => assert_eq!(p, problem),
            other => panic!("{other}"),
        }
    }
    // An unknown chunk after the JSON is skipped; a buffer without a URI and no BIN chunk
    // is named.
    let mut b = glb(
        &json!({"asset": {"version": "2.0"}, "buffers": [{"byteLength": 4}]}).to_string(),
        None,
    );
    b.extend(4u32.to_le_bytes());
    b.extend(b"XTRA");
    b.extend([0; 4]);
    let total = b.len() as u32;
    b[8..12].copy_from_slice(&total.to_le_bytes());
    match refused(&b) {
        MeshError::Buffer {
            buffer: 0,
            problem: BufferProblem::NoData,
        } => {}
        other => panic!("{other}"),
    }
}

#[test]
fn a_valid_document_reads_with_strides_transforms_and_index_sizes() {
    // The triangle interleaved with 4 bytes of padding (stride 16), drawn three times:
    // u8, u16 and u32 indices, by nodes translated along Z, the second under the first.
    let mut bin = Vec::new();
    for p in [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        bin.extend(floats(&p));
        bin.extend([0xAB; 4]);
    }
    bin.extend([0u8, 2, 1, 0]);
    bin.extend([0u8, 0, 2, 0, 1, 0, 0, 0]);
    for i in [0u32, 2, 1] {
        bin.extend(i.to_le_bytes());
    }
    let idx = |view: usize, ct: u32| json!({"bufferView": view, "componentType": ct, "count": 3, "type": "SCALAR"});
    let doc = json!({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": [{"buffer": 0, "byteLength": 48, "byteStride": 16},
                        {"buffer": 0, "byteOffset": 48, "byteLength": 3},
                        {"buffer": 0, "byteOffset": 52, "byteLength": 6},
                        {"buffer": 0, "byteOffset": 60, "byteLength": 12}],
        "accessors": [positions(0, 3), idx(1, 5121), idx(2, 5123), idx(3, 5125)],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1},
                                   {"attributes": {"POSITION": 0}, "indices": 2},
                                   {"attributes": {"POSITION": 0}, "indices": 3},
                                   {"attributes": {"POSITION": 0}, "mode": 1}]}],
        "nodes": [{"mesh": 0, "translation": [0, 0, 1], "children": [1]},
                  {"mesh": 0, "translation": [0, 0, 2]}]
    });
    for bytes in [glb(&doc.to_string(), Some(&bin)), {
        let mut d = doc.clone();
        d["buffers"][0]["uri"] = json!(data_uri(&bin));
        d.to_string().into_bytes()
    }] {
        let (r, u) = parse(&bytes);
        let m = r.unwrap();
        assert!(u.peak < REFUSED, "{u:?}");
        assert_eq!(m.positions.len(), 18);
        assert_eq!(m.positions[4], DVec3::new(1.0, 0.0, 1.0));
        assert_eq!(m.positions[13], DVec3::new(1.0, 0.0, 3.0));
        assert_eq!(m.triangles.len(), 6);
        assert!(m.triangles.iter().enumerate().all(|(t, tri)| {
            let b = 3 * t as u32;
            *tri == [b, b + 2, b + 1]
        }));
        assert_eq!(m.source_positions, m.positions);
    }
}

// ---- The property over valid minimal documents with arbitrary header values ----

/// A header number: small, near a power of two, or an edge, or anything.
fn number() -> impl Strategy<Value = u64> {
    prop_oneof![
        3 => 0u64..100,
        1 => (0u32..64).prop_map(|k| 1u64 << k),
        1 => (0u32..64).prop_map(|k| (1u64 << k).wrapping_sub(1)),
        1 => prop::sample::select(vec![4_000_000_000u64, u64::MAX, u32::MAX as u64]),
        1 => any::<u64>(),
    ]
}

/// A sparse accessor's substitutions: index and value.
type Substitutions = Vec<(u32, [f32; 3])>;

/// A valid minimal document: one triangle-list primitive of `positions` (interleaved
/// with padding up to `stride` bytes), maybe indexed, maybe sparse (substitutions, over
/// the view or over zeros), drawn by a node under a chain of two more, maybe skinned by
/// some of those with inverse bind matrices; its one buffer a GLB BIN chunk or a data
/// URI.
#[derive(Debug, Clone)]
struct Valid {
    as_glb: bool,
    positions: Vec<[f32; 3]>,
    stride: usize,
    /// Component type (5121, 5123, 5125) and the indices.
    indices: Option<(u64, Vec<u32>)>,
    /// Whether the positions' base comes from the view (or is zeros), and the
    /// substitutions (increasing indices).
    sparse: Option<(bool, Substitutions)>,
    /// Joints (nodes 1 to 3, distinct) and whether they have inverse bind matrices.
    skin: Option<(Vec<u64>, bool)>,
}

fn valid() -> impl Strategy<Value = Valid> {
    let point = || prop::array::uniform3(-10.0f32..10.0);
    (1usize..14)
        .prop_flat_map(move |tris| {
            let n = 3 * tris;
            (
                any::<bool>(),
                prop::collection::vec(point(), n),
                prop::sample::select(vec![12usize, 16, 20, 24, 252]),
                prop::option::of((
                    prop::sample::select(vec![5121u64, 5123, 5125]),
                    prop::collection::vec(0..n as u32, 3 * tris),
                )),
                prop::option::weighted(
                    0.3,
                    (
                        any::<bool>(),
                        prop::collection::btree_map(0..n as u32, point(), 1..=n.min(5)),
                    ),
                ),
                prop::option::weighted(
                    0.4,
                    (
                        prop::sample::subsequence(vec![1u64, 2, 3], 1..=3).prop_shuffle(),
                        any::<bool>(),
                    ),
                ),
            )
        })
        .prop_map(|(as_glb, positions, stride, indices, sparse, skin)| Valid {
            as_glb,
            positions,
            stride,
            indices,
            sparse: sparse.map(|(on_view, subs)| (on_view, subs.into_iter().collect())),
            skin,
        })
}

impl Valid {
    /// The document (JSON, and the buffer's bytes).
    fn build(&self) -> (Value, Vec<u8>) {
        let n = self.positions.len();
        let mut data = Vec::new();
        for p in &self.positions {
            data.extend(floats(p));
            data.resize(data.len() + self.stride - 12, 0xEE);
        }
        let mut views = vec![json!({"buffer": 0, "byteLength": self.stride * (n - 1) + 12})];
        if self.stride != 12 {
            views[0]["byteStride"] = json!(self.stride);
        }
        // Appends a view of `bytes` (4-byte aligned) and returns its index.
        let mut add_view = |data: &mut Vec<u8>, bytes: &[u8]| {
            data.resize(data.len().next_multiple_of(4), 0);
            views.push(json!({"buffer": 0, "byteOffset": data.len(), "byteLength": bytes.len()}));
            data.extend(bytes);
            views.len() - 1
        };
        let mut pos = positions(0, n as u64);
        pos["min"] = json!([-10, -10, -10]);
        pos["max"] = json!([10, 10, 10]);
        let mut accessors = vec![pos];
        let mut prim = json!({"attributes": {"POSITION": 0}});
        if let Some((ct, idx)) = &self.indices {
            let bytes: Vec<u8> = match ct {
                5121 => idx.iter().map(|&i| i as u8).collect(),
                5123 => idx.iter().flat_map(|&i| (i as u16).to_le_bytes()).collect(),
                _ => idx.iter().flat_map(|&i| i.to_le_bytes()).collect(),
            };
            let v = add_view(&mut data, &bytes);
            accessors.push(
                json!({"bufferView": v, "componentType": ct, "count": idx.len(), "type": "SCALAR"}),
            );
            prim["indices"] = json!(accessors.len() - 1);
        }
        if let Some((on_view, subs)) = &self.sparse {
            let idx: Vec<u8> = subs.iter().flat_map(|(i, _)| i.to_le_bytes()).collect();
            let val: Vec<u8> = subs.iter().flat_map(|(_, p)| floats(p)).collect();
            let (vi, vv) = (add_view(&mut data, &idx), add_view(&mut data, &val));
            accessors[0]["sparse"] = json!({"count": subs.len(),
                "indices": {"bufferView": vi, "componentType": 5125},
                "values": {"bufferView": vv}});
            if !on_view {
                accessors[0].as_object_mut().unwrap().remove("bufferView");
            }
        }
        let mut nodes = vec![
            json!({"mesh": 0, "children": [1]}),
            json!({"name": "a", "children": [2], "translation": [0, 1, 0]}),
            json!({"name": "b", "children": [3]}),
            json!({"name": "c"}),
        ];
        let mut skins = Vec::new();
        if let Some((joints, with_ibm)) = &self.skin {
            let mut skin = json!({"joints": joints});
            if *with_ibm {
                let m: Vec<f32> = (0..joints.len())
                    .flat_map(|k| DMat4::from_translation(DVec3::Y * k as f64).to_cols_array())
                    .map(|v| v as f32)
                    .collect();
                let v = add_view(&mut data, &floats(&m));
                accessors.push(json!({"bufferView": v, "componentType": 5126, "count": joints.len(), "type": "MAT4"}));
                skin["inverseBindMatrices"] = json!(accessors.len() - 1);
            }
            skins.push(skin);
            nodes[0]["skin"] = json!(0);
        }
        let mut buffer = json!({"byteLength": data.len()});
        if !self.as_glb {
            buffer["uri"] = json!(data_uri(&data));
        }
        let root = json!({
            "asset": {"version": "2.0"},
            "buffers": [buffer],
            "bufferViews": views,
            "accessors": accessors,
            "meshes": [{"primitives": [prim]}],
            "nodes": nodes,
            "skins": skins,
        });
        (root, data)
    }

    /// The positions and triangles the document holds.
    fn expected(&self) -> (Vec<DVec3>, Vec<[u32; 3]>) {
        let mut p: Vec<[f32; 3]> = match &self.sparse {
            Some((false, _)) => vec![[0.0; 3]; self.positions.len()],
            _ => self.positions.clone(),
        };
        for (i, v) in self.sparse.iter().flat_map(|(_, s)| s) {
            p[*i as usize] = *v;
        }
        let idx: Vec<u32> = match &self.indices {
            Some((_, i)) => i.clone(),
            None => (0..p.len() as u32).collect(),
        };
        // Unskinned, the node sits under nothing: its own (identity) transform. Skinned
        // with inverse bind matrices (`T(k·Y)` for the k-th joint) under joints at
        // `T(Y)` (nodes 1 to 3; node 0 at the origin), the mesh moves by their common
        // skinning matrix when all joints share one (a single joint), as glTF shows it.
        let shift = match &self.skin {
            Some((joints, true)) => {
                let world = |n: u64| if n == 0 { 0.0 } else { 1.0 };
                let moves: Vec<f64> = joints
                    .iter()
                    .enumerate()
                    .map(|(k, &n)| world(n) + k as f64)
                    .collect();
                let common = moves.iter().all(|&m| m == moves[0]);
                if common {
                    moves[0]
                } else {
                    0.0
                }
            }
            _ => 0.0,
        };
        let positions = p
            .iter()
            .map(|q| DVec3::from_array(q.map(f64::from)) + DVec3::Y * shift)
            .collect();
        (
            positions,
            idx.chunks(3).map(|t| [t[0], t[1], t[2]]).collect(),
        )
    }
}

/// The header fields a change may hit, as JSON pointers, with the object each is in.
const HEADER_FIELDS: &[&str] = &[
    "/buffers/0/byteLength",
    "/bufferViews/V/buffer",
    "/bufferViews/V/byteOffset",
    "/bufferViews/V/byteLength",
    "/bufferViews/V/byteStride",
    "/accessors/A/bufferView",
    "/accessors/A/byteOffset",
    "/accessors/A/count",
    "/accessors/A/componentType",
    "/accessors/A/type",
    "/accessors/0/sparse/count",
    "/accessors/0/sparse/indices/bufferView",
    "/accessors/0/sparse/indices/byteOffset",
    "/accessors/0/sparse/indices/componentType",
    "/accessors/0/sparse/values/bufferView",
    "/accessors/0/sparse/values/byteOffset",
    "/meshes/0/primitives/0/indices",
    "/skins/0/joints/0",
    "/skins/0/inverseBindMatrices",
    "/nodes/0/mesh",
    "/nodes/2/children/0",
];

/// Sets one header field of `root` (the `V` or `A` of its pointer chosen by `which`) to
/// `value` (a type name for `type`), when the object it belongs to exists.
fn change(root: &mut Value, field: &str, which: usize, value: u64) {
    let n_views = root["bufferViews"].as_array().map_or(1, Vec::len);
    let n_acc = root["accessors"].as_array().map_or(1, Vec::len);
    let ptr = field
        .replace("/V/", &format!("/{}/", which % n_views))
        .replace("/A/", &format!("/{}/", which % n_acc));
    let (parent, key) = ptr.rsplit_once('/').unwrap();
    let new = if key == "type" {
        let types = [
            "SCALAR", "VEC2", "VEC3", "VEC4", "MAT2", "MAT3", "MAT4", "BAD",
        ];
        json!(types[(value % 8) as usize])
    } else {
        json!(value)
    };
    match root.pointer_mut(parent) {
        Some(Value::Object(o)) => {
            o.insert(key.to_string(), new);
        }
        Some(Value::Array(a)) => {
            if let Some(slot) = key.parse::<usize>().ok().and_then(|k| a.get_mut(k)) {
                *slot = new;
            }
        }
        _ => {}
    }
}

/// Reads a document under the meter and checks the bounds and what was read.
fn check(bytes: &[u8]) {
    let (r, u) = parse(bytes);
    if std::env::var_os("RIGLESS_ALLOC_REPORT").is_some() {
        eprintln!(
            "{} bytes: {}, peak {} B, largest {} B",
            bytes.len(),
            match &r {
                Ok(m) => format!("{} vertices", m.positions.len()),
                Err(e) => e.to_string(),
            },
            u.peak,
            u.largest
        );
    }
    u.assert_within(bytes.len(), "glTF");
    // Tighter than the meter's bound: these documents are under 4 KB.
    assert!(u.peak < REFUSED, "{u:?}");
    if let Ok(m) = r {
        let n = m.positions.len() as u32;
        assert!(!m.triangles.is_empty());
        assert!(m.triangles.iter().flatten().all(|&i| i < n));
        assert_eq!(m.source_positions.len(), m.positions.len());
        assert!(m
            .skin_joints
            .iter()
            .enumerate()
            .all(|(k, j)| j.parent.is_none_or(|p| p < k)));
    }
}

fn config() -> Config {
    Config {
        cases: 512,
        failure_persistence: None,
        ..Config::default()
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn valid_minimal_documents_with_arbitrary_header_values_read_within_bounds(
        v in valid(),
        changes in prop::collection::vec(
            (prop::sample::select(HEADER_FIELDS), any::<usize>(), number()),
            0..4,
        ),
    ) {
        let (mut root, data) = v.build();
        for (field, which, value) in &changes {
            change(&mut root, field, *which, *value);
        }
        let bytes = if v.as_glb {
            glb(&root.to_string(), Some(&data))
        } else {
            root.to_string().into_bytes()
        };
        check(&bytes);
        if changes.is_empty() {
            // Unchanged, the document reads as built.
            let m = parse_gltf(&bytes, None).unwrap_or_else(|e| panic!("{e}\n{root}"));
            let (positions, triangles) = v.expected();
            prop_assert_eq!(&m.positions, &positions);
            prop_assert_eq!(&m.triangles, &triangles);
            prop_assert_eq!(m.skin_joints.len(), v.skin.as_ref().map_or(0, |s| s.0.len()));
        }
    }

    #[test]
    fn plausible_documents_read_and_every_index_is_checked(
        as_glb in any::<bool>(),
        n in 1usize..40,
        raw in prop::collection::vec(any::<u8>(), 0..200),
        stride in prop::option::of(prop::sample::select(vec![12u64, 16, 20, 252])),
        index_type in prop::sample::select(vec![5121u64, 5123, 5125]),
    ) {
        // Sizes that fit, contents arbitrary: positions (may be NaN) and indices (may be
        // out of range), so the reader's own checks decide.
        let s = stride.unwrap_or(12) as usize;
        let pos_len = s * (n - 1) + 12;
        let isz = match index_type { 5121 => 1, 5123 => 2, _ => 4 };
        let count = (raw.len() / isz / 3) * 3;
        let mut data = vec![0u8; pos_len];
        for (k, b) in data.iter_mut().enumerate() {
            *b = raw.get(k % raw.len().max(1)).copied().unwrap_or(0);
        }
        data.extend(raw.iter().take(count * isz));
        let mut views = vec![json!({"buffer": 0, "byteLength": pos_len})];
        if let Some(st) = stride {
            views[0]["byteStride"] = json!(st);
        }
        views.push(json!({"buffer": 0, "byteOffset": pos_len, "byteLength": count * isz}));
        let mut prim = json!({"attributes": {"POSITION": 0}});
        if count > 0 {
            prim["indices"] = json!(1);
        }
        let mut buffer = json!({"byteLength": data.len()});
        if !as_glb {
            buffer["uri"] = json!(data_uri(&data));
        }
        let root = json!({
            "asset": {"version": "2.0"},
            "buffers": [buffer],
            "bufferViews": views,
            "accessors": [positions(0, n as u64),
                          {"bufferView": 1, "componentType": index_type, "count": count, "type": "SCALAR"}],
            "meshes": [{"primitives": [prim]}],
            "nodes": [{"mesh": 0}]
        });
        let bytes = if as_glb {
            glb(&root.to_string(), Some(&data))
        } else {
            root.to_string().into_bytes()
        };
        check(&bytes);
        let r = parse_gltf(&bytes, None);
        if count == 0 {
            match r {
                Ok(m) => prop_assert!(n % 3 == 0 && m.triangles.len() == n / 3),
                Err(e) => prop_assert!(n % 3 != 0, "{}", e),
            }
        } else {
            let bad = raw.chunks(isz).take(count).any(|c| {
                let mut w = [0u8; 4];
                w[..isz].copy_from_slice(c);
                u32::from_le_bytes(w) as usize >= n
            });
            match r {
                Ok(m) => prop_assert!(!bad && m.triangles.len() == count / 3),
                Err(e) => prop_assert!(bad, "{}", e),
            }
        }
    }

    #[test]
    fn arbitrary_json_values_in_a_document_never_panic(
        edits in prop::collection::vec((0usize..400, any::<u8>()), 1..6)
    ) {
        // A valid document with a few bytes of its JSON replaced.
        let base = json!({
            "asset": {"version": "2.0"},
            "buffers": [{"byteLength": 36, "uri": data_uri(&triangle_bytes())}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}],
            "accessors": [positions(0, 3)],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "nodes": [{"mesh": 0}]
        })
        .to_string();
        let mut b = base.into_bytes();
        for (at, v) in edits {
            let k = at % b.len();
            b[k] = v;
        }
        check(&b);
    }
}

// ---- The real assets, as the gltf crate reads them ----

fn shared(rel: &str) -> Option<PathBuf> {
    common::shared_path(rel)
}

/// The reader as it was before (the `gltf` crate's buffers and accessor readers, and the
/// old joint order), for comparison on files that crate reads without trouble.
fn read_with_the_crate(path: &Path) -> MeshData {
    let g = gltf::Gltf::from_slice(&std::fs::read(path).unwrap()).unwrap();
    let buffers = gltf::import_buffers(&g.document, path.parent(), g.blob.clone()).unwrap();
    let doc = &g.document;
    let n_nodes = doc.nodes().len();
    let mut parent: Vec<Option<usize>> = vec![None; n_nodes];
    for n in doc.nodes() {
        for c in n.children() {
            parent[c.index()] = Some(n.index());
        }
    }
    let local: Vec<DMat4> = doc
        .nodes()
        .map(|n| DMat4::from_cols_array_2d(&n.transform().matrix().map(|c| c.map(f64::from))))
        .collect();
    let world = |mut i: usize| {
        let mut m = local[i];
        while let Some(p) = parent[i] {
            m = local[p] * m;
            i = p;
        }
        m
    };
    let mut out = MeshData::default();
    let mut first_skin = None;
    // The first skin's joints some vertex has weight on (the files here have one skin).
    let mut weighted: Vec<bool> = Vec::new();
    for node in doc.nodes() {
        let Some(mesh) = node.mesh() else { continue };
        let xf = match node.skin() {
            Some(_) => DMat4::IDENTITY,
            None => world(node.index()),
        };
        first_skin = first_skin.or(node.skin());
        for prim in mesh.primitives() {
            if prim.mode() != gltf::mesh::Mode::Triangles {
                continue;
            }
            let reader = prim.reader(|b| Some(&buffers[b.index()].0[..]));
            let base = out.positions.len() as u32;
            out.positions.extend(
                reader
                    .read_positions()
                    .unwrap()
                    .map(|p| xf.transform_point3(DVec3::from_array(p.map(f64::from)))),
            );
            if let (Some(s), Some(j), Some(w)) =
                (node.skin(), reader.read_joints(0), reader.read_weights(0))
            {
                let n = s.joints().count();
                weighted.resize(n, false);
                for (j, w) in j.into_u16().zip(w.into_f32()) {
                    for c in 0..4 {
                        if w[c] > 0.0 && (j[c] as usize) < n {
                            weighted[j[c] as usize] = true;
                        }
                    }
                }
            }
            let idx: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
            out.triangles.extend(
                idx.chunks_exact(3)
                    .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
            );
        }
    }
    out.source_positions = out.positions.clone();
    let skin = first_skin.unwrap();
    let joints: Vec<gltf::Node> = skin.joints().collect();
    if weighted.is_empty() {
        weighted = vec![true; joints.len()];
    }
    let ibm: Vec<DMat4> = skin
        .reader(|b| Some(&buffers[b.index()].0[..]))
        .read_inverse_bind_matrices()
        .unwrap()
        .map(|m| DMat4::from_cols_array_2d(&m.map(|c| c.map(f64::from))))
        .collect();
    // The old order: by depth among the joints, the skin's order among equals.
    let slot = |node: usize| joints.iter().position(|j| j.index() == node);
    let joint_parent = |k: usize| {
        let mut i = joints[k].index();
        while let Some(p) = parent[i] {
            if let Some(s) = slot(p) {
                return Some(s);
            }
            i = p;
        }
        None
    };
    let depth = |mut k: usize| {
        let mut d = 0;
        while let Some(p) = joint_parent(k) {
            d += 1;
            k = p;
        }
        d
    };
    let mut order: Vec<usize> = (0..joints.len()).collect();
    order.sort_by_key(|&k| (depth(k), k));
    let new_index = |k: usize| order.iter().position(|&o| o == k).unwrap();
    for &k in &order {
        out.skin_joints.push(rigless::character::mesh::SkinJoint {
            name: joints[k].name().unwrap().to_string(),
            parent: joint_parent(k).map(new_index),
            world_from_joint: ibm[k].inverse(),
            weighted: weighted[k],
        });
    }
    out
}

#[test]
fn real_assets_read_as_the_gltf_crate_reads_them() {
    let files = [
        "meshes/gltf-samples/CesiumMan.glb",
        "meshes/gltf-samples/RiggedSimple.glb",
        "meshes/webxr-generic-hand/left.glb",
        "meshes/webxr-generic-hand/right.glb",
    ];
    for rel in files {
        let Some(path) = shared(rel) else { continue };
        let bytes = std::fs::read(&path).unwrap();
        let (ours, u) = measure(|| read_gltf(&path));
        let ours = ours.unwrap_or_else(|e| panic!("{rel}: {e}"));
        u.assert_within(bytes.len(), rel);
        eprintln!(
            "{rel}: {} bytes, {} vertices, {} triangles, {} joints, peak {} B",
            bytes.len(),
            ours.positions.len(),
            ours.triangles.len(),
            ours.skin_joints.len(),
            u.peak
        );
        let theirs = read_with_the_crate(&path);
        assert_eq!(ours.triangles, theirs.triangles, "{rel}");
        assert_eq!(ours.positions.len(), theirs.positions.len(), "{rel}");
        let worst = ours
            .positions
            .iter()
            .zip(&theirs.positions)
            .map(|(a, b)| (*a - *b).length() / b.length().max(1.0))
            .fold(0.0f64, f64::max);
        assert!(worst < 1e-12, "{rel}: {worst}");
        // Ours adds end joints to leaves whose skin reaches past them (each `NAME_end`,
        // unweighted, under a joint the crate's reading has as a leaf).
        let (same, ends) = ours
            .skin_joints
            .split_at(theirs.skin_joints.len().min(ours.skin_joints.len()));
        assert_eq!(same.len(), theirs.skin_joints.len(), "{rel}");
        for e in ends {
            let parent = e.parent.map(|p| &ours.skin_joints[p]);
            let leaf = |p: usize| !theirs.skin_joints.iter().any(|t| t.parent == Some(p));
            assert!(
                parent.is_some_and(|p| e.name == format!("{}_end", p.name))
                    && !e.weighted
                    && e.parent.is_some_and(leaf),
                "{rel}: {}",
                e.name
            );
        }
        for (j, t) in same.iter().zip(&theirs.skin_joints) {
            assert_eq!(
                (&j.name, j.parent, j.world_from_joint, j.weighted),
                (&t.name, t.parent, t.world_from_joint, t.weighted),
                "{rel}"
            );
        }
    }
}

/// Joints without names, or with a name an earlier joint has, get stable names of their
/// own from their node: the skeleton's names stay unique and the file binds.
#[test]
fn unnamed_and_repeated_joint_names_are_made_unique() {
    let mut doc = skinned_doc(&[1, 2, 3], 3);
    doc["nodes"][2]["name"] = json!("bone0");
    doc["nodes"][3].as_object_mut().unwrap().remove("name");
    let bytes = glb(&doc.to_string(), Some(&triangle_bytes()));
    let m = parse_gltf(&bytes, None).unwrap();
    let names: Vec<&str> = m.skin_joints.iter().map(|j| j.name.as_str()).collect();
    assert_eq!(names, ["bone0", "bone0#2", "joint3"]);
}

/// A skinned mesh whose joints hang under a node that turns Z up to Y up and scales by
/// 0.01 (the rest pose being the bind pose) is read in the world that node makes, its
/// joints too; when its joints' rest transforms disagree (a rest pose other than the
/// bind pose), it is read in bind space as stored.
#[test]
fn a_skin_under_a_scaled_turned_armature_reads_in_the_world() {
    let p: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [100.0, 0.0, 0.0], [0.0, 0.0, 180.0]];
    let mut bin: Vec<u8> = p.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
    // Identity inverse bind matrices for both joints (the bind pose at their nodes).
    let identity = DMat4::IDENTITY.to_cols_array().map(|x| x as f32);
    for _ in 0..2 {
        bin.extend(identity.iter().flat_map(|x| x.to_le_bytes()));
    }
    let doc = |joint_b_rotation: [f64; 4]| {
        json!({
            "asset": {"version": "2.0"},
            "buffers": [{"byteLength": 164}],
            "bufferViews": [{"buffer": 0, "byteLength": 36},
                            {"buffer": 0, "byteOffset": 36, "byteLength": 128}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                           "min": [0, 0, 0], "max": [100, 0, 180]},
                          {"bufferView": 1, "componentType": 5126, "count": 2, "type": "MAT4"}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "nodes": [
                {"name": "Armature", "children": [1, 3],
                 "rotation": [-std::f64::consts::FRAC_1_SQRT_2, 0, 0, std::f64::consts::FRAC_1_SQRT_2],
                 "scale": [0.01, 0.01, 0.01]},
                {"name": "hips", "children": [2]},
                {"name": "head", "rotation": joint_b_rotation},
                {"name": "body", "mesh": 0, "skin": 0}
            ],
            "skins": [{"joints": [1, 2], "inverseBindMatrices": 1}]
        })
        .to_string()
    };
    let m = parse_gltf(&glb(&doc([0.0, 0.0, 0.0, 1.0]), Some(&bin)), None).unwrap();
    // Z up turned Y up, centimetres to metres: (0, 0, 180) is (0, 1.8, 0).
    let want = [
        DVec3::ZERO,
        DVec3::new(1.0, 0.0, 0.0),
        DVec3::new(0.0, 1.8, 0.0),
    ];
    for (got, want) in m.positions.iter().zip(&want) {
        assert!((*got - *want).length() < 1e-6, "{got} vs {want}");
    }
    assert!(m.rest_from_bind.is_some());
    let head = &m.skin_joints[1];
    assert!((head.world_from_joint.w_axis.truncate()).length() < 1e-9);
    // The head turned at rest: the rest pose is not the bind pose, kept as stored.
    let turned = doc([0.0, 0.0, 0.3826834, 0.9238795]);
    let m = parse_gltf(&glb(&turned, Some(&bin)), None).unwrap();
    assert_eq!(m.positions[2], DVec3::new(0.0, 0.0, 180.0));
    assert!(m.rest_from_bind.is_none());
}

/// Which joints carry skin weight is read from `JOINTS_0` and `WEIGHTS_0` (unsigned
/// bytes and normalised bytes here): a joint no vertex is weighted to is marked so.
#[test]
fn joints_without_skin_weight_are_told_apart() {
    let p: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let mut bin: Vec<u8> = p.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
    // JOINTS_0: every vertex on joint 0 (and joint 2 with weight 0); WEIGHTS_0: 255, 0.
    for _ in 0..3 {
        bin.extend([0u8, 2, 0, 0]);
    }
    for _ in 0..3 {
        bin.extend([255u8, 0, 0, 0]);
    }
    let doc = json!({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": [{"buffer": 0, "byteLength": 36},
                        {"buffer": 0, "byteOffset": 36, "byteLength": 12},
                        {"buffer": 0, "byteOffset": 48, "byteLength": 12}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
             "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5121, "count": 3, "type": "VEC4"},
            {"bufferView": 2, "componentType": 5121, "normalized": true, "count": 3, "type": "VEC4"}
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "JOINTS_0": 1, "WEIGHTS_0": 2}}]}],
        "nodes": [
            {"name": "hips", "children": [2]},
            {"name": "knee_pole"},
            {"name": "foot_ik"},
            {"name": "body", "mesh": 0, "skin": 0}
        ],
        "skins": [{"joints": [0, 1, 2]}]
    });
    let m = parse_gltf(&glb(&doc.to_string(), Some(&bin)), None).unwrap();
    let flags: Vec<(&str, bool)> = m
        .skin_joints
        .iter()
        .map(|j| (j.name.as_str(), j.weighted))
        .collect();
    assert_eq!(
        flags,
        [("hips", true), ("knee_pole", false), ("foot_ik", false)]
    );
}
