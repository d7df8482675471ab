use super::*;

fn parse(bytes: &[u8]) -> Result<NpyArray> {
    parse_npy(Path::new("poses_bounds.npy"), bytes)
}

/// `bytes` with the first occurrence of `from` replaced by `to` (same length).
fn replace(bytes: &[u8], from: &[u8], to: &[u8]) -> Vec<u8> {
    let at = bytes.windows(from.len()).position(|w| w == from).unwrap();
    let mut out = bytes.to_vec();
    out[at..at + to.len()].copy_from_slice(to);
    out
}

fn err(bytes: &[u8]) -> String {
    parse(bytes).unwrap_err().to_string()
}

#[test]
fn reads_v1_and_v2_headers_of_f8_and_f4() {
    let values = [1.5, -2.0, 3.25, 0.0, 1e-3, 7.0];
    for v2 in [false, true] {
        let a = parse(&encode_npy(&[2, 3], &f8_bytes(&values), "<f8", false, v2)).unwrap();
        assert_eq!(a.shape, vec![2, 3]);
        assert_eq!(a.data, values);
    }
    let f4: Vec<u8> = [0.5f32, -1.25, 3.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let a = parse(&encode_npy(&[3], &f4, "<f4", false, false)).unwrap();
    assert_eq!((a.shape, a.data), (vec![3], vec![0.5, -1.25, 3.0]));
    // numpy's own v1 header for a (17, 17) array, byte for byte (LLFF's poses_bounds.npy).
    let header = "{'descr': '<f8', 'fortran_order': False, 'shape': (17, 17), }";
    let mut bytes = b"\x93NUMPY\x01\x00\x76\x00".to_vec();
    bytes.extend(format!("{header:<117}\n").bytes());
    assert_eq!(bytes.len(), 128);
    bytes.extend(f8_bytes(&[2.0; 289]));
    let a = parse(&bytes).unwrap();
    assert_eq!(a.shape, vec![17, 17]);
    assert!(a.data.iter().all(|&v| v == 2.0));
}

#[test]
fn reads_v3_scalars_and_double_quotes() {
    let mut bytes = b"\x93NUMPY\x03\x00".to_vec();
    let header = "{\"descr\": \"<f8\", \"shape\": (), \"fortran_order\": False}\n";
    bytes.extend((header.len() as u32).to_le_bytes());
    bytes.extend(header.bytes());
    bytes.extend(4.0f64.to_le_bytes());
    let a = parse(&bytes).unwrap();
    assert_eq!((a.shape, a.data), (vec![], vec![4.0]));
}

#[test]
fn fortran_order_is_transposed_to_row_major() {
    // [[1, 2, 3], [4, 5, 6]] stored column by column: 1 4 2 5 3 6.
    let body = f8_bytes(&[1.0, 4.0, 2.0, 5.0, 3.0, 6.0]);
    let a = parse(&encode_npy(&[2, 3], &body, "<f8", true, false)).unwrap();
    assert_eq!(a.data, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
    // 3-d: element (i, j, k) of shape (2, 2, 2) has value 100i + 10j + k; Fortran order
    // walks i fastest.
    let mut fortran = Vec::new();
    for k in 0..2 {
        for j in 0..2 {
            for i in 0..2 {
                fortran.push((100 * i + 10 * j + k) as f64);
            }
        }
    }
    let a = parse(&encode_npy(
        &[2, 2, 2],
        &f8_bytes(&fortran),
        "<f8",
        true,
        false,
    ))
    .unwrap();
    assert_eq!(
        a.data,
        vec![0.0, 1.0, 10.0, 11.0, 100.0, 101.0, 110.0, 111.0]
    );
}

#[test]
fn bad_files_give_clear_errors() {
    let good = encode_npy(&[2, 2], &f8_bytes(&[1.0; 4]), "<f8", false, false);
    let e = err(b"PK\x03\x04 a zip, not npy");
    assert!(e.contains("poses_bounds.npy") && e.contains("magic"), "{e}");
    let mut v9 = good.clone();
    v9[6] = 9;
    assert!(err(&v9).contains("version 9"), "{}", err(&v9));
    let e = err(&good[..9]);
    assert!(e.contains("truncated"), "{e}");
    // A header length beyond the file.
    let mut long = good.clone();
    long[8] = 0xff;
    long[9] = 0xff;
    let e = err(&long);
    assert!(e.contains("header length 65535 runs past the end"), "{e}");
    // Data shorter than the shape needs (checked before allocating).
    let e = err(&good[..good.len() - 3]);
    assert!(e.contains("needs 32 bytes of data, the file has 29"), "{e}");
    // A huge shape in a tiny file is an error, not an allocation.
    let e = err(&encode_npy(&[1 << 40, 1 << 30], &[], "<f8", false, false));
    assert!(e.contains("overflows") || e.contains("needs"), "{e}");
    let e = err(&encode_npy(&[2], &f8_bytes(&[1.0; 2]), ">f8", false, false));
    assert!(e.contains("big-endian"), "{e}");
    let e = err(&encode_npy(&[2], &[0; 16], "<i8", false, false));
    assert!(e.contains("'<i8' is not supported"), "{e}");
    let e = err(&replace(&good, b"'shape'", b"'shope'"));
    assert!(e.contains("unexpected key 'shope'"), "{e}");
    let e = err(&replace(&good, b"(2, 2)", b"(2, x)"));
    assert!(e.contains("\"x\" is not a size"), "{e}");
    let e = err(&replace(&good, b"False", b"Maybe"));
    assert!(e.contains("unexpected value \"Maybe\""), "{e}");
}

#[test]
fn read_npy_names_a_missing_file() {
    let e = read_npy(Path::new("/nonexistent/poses_bounds.npy"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nonexistent/poses_bounds.npy"), "{e}");
}
