//! Hostile `.pth` / pickle and safetensors inputs (issue 10 defect 4): every case is a clear
//! error naming the file, never a panic, an abort or an allocation driven by a header value.

use std::path::Path;

use depthsense_weights::pickle::{parse_pickle, MAX_PICKLE_DEPTH};
use depthsense_weights::safetensors::{parse as parse_safetensors, serialize};
use depthsense_weights::torch_file::read_torch_bytes;
use depthsense_weights::{DType, HostTensor};

fn f32_tensor(values: &[f32], shape: &[i64]) -> HostTensor<'static> {
    HostTensor {
        dtype: DType::F32,
        shape: shape.to_vec(),
        data: values
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect::<Vec<u8>>()
            .into(),
    }
}

const LEGACY_MAGIC: [u8; 10] = [0x6c, 0xfc, 0x9c, 0x46, 0xf9, 0x20, 0x6a, 0xa8, 0x50, 0x19];

fn s(out: &mut Vec<u8>, x: &str) {
    out.push(b'X');
    out.extend_from_slice(&(x.len() as u32).to_le_bytes());
    out.extend_from_slice(x.as_bytes());
}

fn int(out: &mut Vec<u8>, v: i64) {
    out.push(0x8a);
    out.push(8);
    out.extend_from_slice(&v.to_le_bytes());
}

fn int_tuple(out: &mut Vec<u8>, xs: &[i64]) {
    out.push(b'(');
    for &x in xs {
        int(out, x);
    }
    out.push(b't');
}

/// A legacy (pre-1.6) `torch.save` file holding `{"w": FloatStorage view}` with the given
/// view and a storage of `numel` floats.
fn legacy_file(size: &[i64], stride: &[i64], offset: i64, numel: u64) -> Vec<u8> {
    let mut b = vec![0x80, 2, 0x8a, 10];
    b.extend_from_slice(&LEGACY_MAGIC);
    b.push(b'.');
    b.extend_from_slice(&[0x80, 2, b'K', 2, b'.']); // protocol
    b.extend_from_slice(&[0x80, 2, b'}', b'.']); // sys info
    b.extend_from_slice(&[0x80, 2, b'}']);
    s(&mut b, "w");
    b.extend_from_slice(b"ctorch._utils\n_rebuild_tensor_v2\n(");
    b.push(b'(');
    s(&mut b, "storage");
    b.extend_from_slice(b"ctorch\nFloatStorage\n");
    s(&mut b, "0");
    s(&mut b, "cpu");
    int(&mut b, numel as i64);
    b.push(b't');
    b.push(b'Q');
    int(&mut b, offset);
    int_tuple(&mut b, size);
    int_tuple(&mut b, stride);
    b.push(0x89);
    b.extend_from_slice(b"ccollections\nOrderedDict\n)R");
    b.extend_from_slice(b"tRs.");
    b.extend_from_slice(&[0x80, 2, b'(']);
    s(&mut b, "0");
    b.extend_from_slice(b"l.");
    b.extend_from_slice(&numel.to_le_bytes());
    for i in 0..numel.min(1 << 20) {
        b.extend_from_slice(&(i as f32).to_le_bytes());
    }
    b
}

fn err_of(bytes: &[u8], name: &str) -> String {
    let e = read_torch_bytes(Path::new(name), bytes)
        .err()
        .unwrap_or_else(|| panic!("{name}: hostile file was accepted"))
        .to_string();
    assert!(e.contains(name), "{e}");
    e
}

#[test]
fn legacy_builder_makes_a_readable_file() {
    let t = read_torch_bytes(Path::new("ok.pth"), &legacy_file(&[2, 3], &[3, 1], 0, 6)).unwrap();
    assert_eq!(t.len(), 1);
    assert_eq!(t[0].1.shape, [2, 3]);
    assert_eq!(t[0].1, f32_tensor(&[0.0, 1.0, 2.0, 3.0, 4.0, 5.0], &[2, 3]));
    // a transposed view is gathered into row-major order
    let t = read_torch_bytes(Path::new("t.pth"), &legacy_file(&[3, 2], &[1, 3], 0, 6)).unwrap();
    assert_eq!(t[0].1, f32_tensor(&[0.0, 3.0, 1.0, 4.0, 2.0, 5.0], &[3, 2]));
    // an offset, a broadcast (stride 0) and an empty view
    let t = read_torch_bytes(Path::new("o.pth"), &legacy_file(&[2, 2], &[0, 2], 1, 6)).unwrap();
    assert_eq!(t[0].1, f32_tensor(&[1.0, 3.0, 1.0, 3.0], &[2, 2]));
    let t = read_torch_bytes(Path::new("e.pth"), &legacy_file(&[0, 3], &[3, 1], 0, 6)).unwrap();
    assert_eq!(t[0].1, f32_tensor(&[], &[0, 3]));
}

#[test]
fn tensor_views_with_hostile_sizes_are_errors() {
    // (s-1)·stride overflows i64: in release it used to wrap past the bounds check.
    let e = err_of(
        &legacy_file(&[1 << 62, 5], &[1 << 62, 1], 0, 6),
        "overflow.pth",
    );
    assert!(e.contains("overflows") || e.contains("64 bits"), "{e}");
    // a stride-0 view of 10^12 elements from 6 floats: refused before `contiguous()`
    let e = err_of(&legacy_file(&[1_000_000_000_000], &[0], 0, 6), "expand.pth");
    assert!(e.contains("expands"), "{e}");
    // negative strides / offsets, mismatched lengths
    err_of(&legacy_file(&[2, 3], &[-3, 1], 5, 6), "neg.pth");
    err_of(&legacy_file(&[2, 3], &[3, 1], -1, 6), "negoff.pth");
    err_of(&legacy_file(&[2, 3], &[3], 0, 6), "rank.pth");
    err_of(&legacy_file(&[2, 3], &[3, 1], 1, 6), "past.pth");
}

#[test]
fn legacy_storage_claiming_huge_sizes_is_an_error() {
    let mut b = legacy_file(&[2, 3], &[3, 1], 0, 6);
    let at = b.len() - 6 * 4 - 8;
    for claim in [u64::MAX, u64::MAX / 4 + 1, 1 << 40] {
        b[at..at + 8].copy_from_slice(&claim.to_le_bytes());
        let e = err_of(&b, "legacy-huge.pth");
        assert!(e.contains("truncated"), "{e}");
    }
}

#[test]
fn pickle_length_fields_past_the_end_are_errors() {
    for bytes in [
        &[0x80, 2, b'X', 0xff, 0xff, 0xff, 0xff, b'a'][..],
        &[
            0x80, 4, 0x8d, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, b'a',
        ][..],
        &[
            0x80, 4, 0x8d, 0xf0, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0x7f,
        ][..],
        &[0x80, 2, b'B', 0xff, 0xff, 0xff, 0x7f][..],
        &[0x80, 2, 0x8a, 0xff, 1, 2][..],
        &[0x80, 2, b'c', b'a', b'\n'][..],
        &[0x80, 2, b'q'][..],
        &[][..],
    ] {
        let e = parse_pickle(bytes).unwrap_err().to_string();
        assert!(
            e.contains("truncated") || e.contains("underflow") || e.contains("empty"),
            "{e}"
        );
    }
}

#[test]
fn memo_bomb_is_refused() {
    // x = []; repeat 64×: x = (x, x) via memo — 2^64 nodes if copied naively.
    let mut b = vec![0x80, 2, b']', b'q', 0];
    for _ in 0..64 {
        b.extend_from_slice(&[b'h', 0, b'h', 0, 0x86, b'q', 0]);
    }
    b.push(b'.');
    let e = parse_pickle(&b).unwrap_err().to_string();
    assert!(e.contains("memo"), "{e}");
    // the same with DUP
    let mut b = vec![0x80, 2, b']'];
    for _ in 0..64 {
        b.extend_from_slice(&[b'2', 0x86]);
    }
    b.push(b'.');
    assert!(parse_pickle(&b).unwrap_err().to_string().contains("memo"));
}

#[test]
fn deep_nesting_is_refused_without_overflowing_the_stack() {
    // 1,000,000 nested tuples would overflow the stack when dropped or walked.
    let n = 1_000_000;
    let mut tuple1 = vec![0x80, 2, b')'];
    tuple1.extend(std::iter::repeat_n(0x85, n));
    let mut marks = vec![0x80, 2];
    marks.extend(std::iter::repeat_n(b'(', n));
    marks.extend(std::iter::repeat_n(b't', n));
    let mut lists = vec![0x80, 2];
    for _ in 0..n {
        lists.extend_from_slice(b"(]");
    }
    lists.extend(std::iter::repeat_n(b'e', n));
    for mut b in [tuple1, marks, lists] {
        b.push(b'.');
        let e = parse_pickle(&b).unwrap_err().to_string();
        assert!(
            e.contains(&format!("deeper than {MAX_PICKLE_DEPTH}")),
            "{e}"
        );
    }
}

/// Needs the `.pth` writer (feature `pth-writer`, on in `cargo test --workspace`: the model's
/// and the fuzzer's tests enable it).
#[cfg(feature = "pth-writer")]
#[test]
fn zip_archive_garbage_and_cuts_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("ok.pth");
    let t = f32_tensor(&[1.0, 2.0, 3.0, 4.0], &[2, 2]);
    depthsense_weights::pth_writer::write_torch_state_dict(&p, &[("a.b".into(), t.clone())])
        .unwrap();
    let good = std::fs::read(&p).unwrap();
    assert_eq!(
        read_torch_bytes(&p, &good).unwrap(),
        vec![("a.b".to_string(), t)]
    );
    for cut in (0..good.len()).step_by(7) {
        let _ = read_torch_bytes(Path::new("cut.pth"), &good[..cut]);
    }
    let mut b = good.clone();
    for i in (0..b.len()).step_by(13) {
        b[i] ^= 0x5a;
        let _ = read_torch_bytes(Path::new("flip.pth"), &b);
        b[i] ^= 0x5a;
    }
    err_of(b"PK\x03\x04garbage", "garbage.pth");
}

#[test]
fn safetensors_with_hostile_shapes_are_errors() {
    let t = f32_tensor(&[1.0, 2.0], &[2]);
    let good = serialize(&[("x".into(), t)], &Default::default());
    assert_eq!(
        parse_safetensors(Path::new("ok"), &good).unwrap().0.len(),
        1
    );
    let header = |h: &str| {
        let mut b = (h.len() as u64).to_le_bytes().to_vec();
        b.extend_from_slice(h.as_bytes());
        b.extend_from_slice(&[0u8; 8]);
        b
    };
    for (h, want) in [
        // 2^32 × 2^32 elements: the product overflows
        (
            r#"{"x":{"dtype":"F32","shape":[4294967296,4294967296],"data_offsets":[0,0]}}"#,
            "overflows",
        ),
        (
            r#"{"x":{"dtype":"F32","shape":[-2,-1],"data_offsets":[0,8]}}"#,
            "non-negative",
        ),
        (
            r#"{"x":{"dtype":"F32","shape":[2,"a"],"data_offsets":[0,8]}}"#,
            "non-negative",
        ),
        (
            r#"{"x":{"dtype":"F32","shape":[2],"data_offsets":[0,18446744073709551615]}}"#,
            "bytes for shape",
        ),
        (
            r#"{"x":{"dtype":"F32","shape":[4],"data_offsets":[0,16]}}"#,
            "truncated",
        ),
    ] {
        let e = parse_safetensors(Path::new("hostile.safetensors"), &header(h))
            .err()
            .unwrap_or_else(|| panic!("accepted {h}"))
            .to_string();
        assert!(e.contains("hostile.safetensors") && e.contains(want), "{e}");
    }
    let mut b = good.clone();
    b[..8].copy_from_slice(&u64::MAX.to_le_bytes());
    assert!(parse_safetensors(Path::new("len"), &b).is_err());
}
