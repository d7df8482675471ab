//! Reading NumPy `.npy` files (format versions 1.0, 2.0 and 3.0) of little-endian `f8`/`f4`
//! numbers, as LLFF's `poses_bounds.npy`.
//!
//! The layout: the magic `\x93NUMPY`, the version (major, minor), the header length (`u16`
//! little-endian in v1, `u32` in v2/v3), then a Python dict literal such as
//! `{'descr': '<f8', 'fortran_order': False, 'shape': (17, 17), }` padded with spaces and a
//! newline, then the raw data. Everything is checked against the file's length before any
//! buffer of the announced size is allocated.

use std::path::Path;

use crate::error::{Error, Result};

const MAGIC: &[u8] = b"\x93NUMPY";

/// A numeric array read from a `.npy` file.
///
/// # Shapes
/// `data`: `[shape.iter().product()]`, row-major (C order) whatever the file's order.
#[derive(Debug, Clone, PartialEq)]
pub struct NpyArray {
    /// The array's dimensions (empty for a scalar).
    pub shape: Vec<usize>,
    /// The values, converted to `f64`, in row-major order.
    pub data: Vec<f64>,
}

/// The element types this reader accepts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Dtype {
    F4,
    F8,
}

impl Dtype {
    fn size(self) -> usize {
        match self {
            Dtype::F4 => 4,
            Dtype::F8 => 8,
        }
    }
}

/// Reads a `.npy` file; errors name the file and the problem.
pub fn read_npy(path: &Path) -> Result<NpyArray> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_npy(path, &bytes)
}

/// Parses the bytes of a `.npy` file (`path` is only used in error messages).
pub fn parse_npy(path: &Path, bytes: &[u8]) -> Result<NpyArray> {
    let bad = |problem: String| Error::invalid(path, problem);
    if bytes.len() < MAGIC.len() + 2 || &bytes[..MAGIC.len()] != MAGIC {
        return Err(bad("not a .npy file (no \\x93NUMPY magic)".into()));
    }
    let major = bytes[6];
    let (len_bytes, utf8) = match major {
        1 => (2, false),
        2 => (4, false),
        3 => (4, true),
        v => {
            return Err(bad(format!(
                ".npy format version {v} is not supported (1, 2 or 3)"
            )));
        }
    };
    let start = 8 + len_bytes;
    if bytes.len() < start {
        return Err(bad("truncated .npy header length".into()));
    }
    let header_len = if len_bytes == 2 {
        u16::from_le_bytes([bytes[8], bytes[9]]) as usize
    } else {
        u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize
    };
    let data_start = start
        .checked_add(header_len)
        .filter(|&end| end <= bytes.len())
        .ok_or_else(|| {
            bad(format!(
                "header length {header_len} runs past the end of the file ({} bytes)",
                bytes.len()
            ))
        })?;
    let raw = &bytes[start..data_start];
    let header = if utf8 {
        String::from_utf8(raw.to_vec()).map_err(|_| bad("header is not UTF-8".into()))?
    } else {
        // v1/v2 headers are latin-1: every byte is one character.
        raw.iter().map(|&b| b as char).collect()
    };
    let header =
        parse_header(&header).map_err(|p| bad(format!("header {:?}: {p}", header.trim_end())))?;

    let count = header
        .shape
        .iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d))
        .ok_or_else(|| bad(format!("shape {:?} overflows", header.shape)))?;
    let expected = count
        .checked_mul(header.dtype.size())
        .ok_or_else(|| bad(format!("shape {:?} overflows", header.shape)))?;
    let available = bytes.len() - data_start;
    if available != expected {
        let what = if available < expected { "truncated" } else { "extra bytes after the data" };
        return Err(bad(format!(
            "shape {:?} of {} needs {expected} bytes of data, the file has {available} ({what})",
            header.shape,
            header.descr()
        )));
    }
    let body = &bytes[data_start..];
    let values: Vec<f64> = match header.dtype {
        Dtype::F8 => body
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("chunks of 8")))
            .collect(),
        Dtype::F4 => body
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("chunks of 4")) as f64)
            .collect(),
    };
    let data = if header.fortran_order {
        fortran_to_c(&values, &header.shape)
    } else {
        values
    };
    Ok(NpyArray {
        shape: header.shape,
        data,
    })
}

/// The fields of a `.npy` header dict.
#[derive(Debug, PartialEq)]
struct Header {
    dtype: Dtype,
    fortran_order: bool,
    shape: Vec<usize>,
}

impl Header {
    fn descr(&self) -> &'static str {
        match self.dtype {
            Dtype::F4 => "<f4",
            Dtype::F8 => "<f8",
        }
    }
}

/// A value of the header dict.
#[derive(Debug, PartialEq)]
enum Literal {
    Str(String),
    Bool(bool),
    Tuple(Vec<usize>),
}

/// Parses `{'descr': '<f8', 'fortran_order': False, 'shape': (3, 4), }`; the error is the
/// problem alone (the caller adds the file).
fn parse_header(text: &str) -> std::result::Result<Header, String> {
    let mut p = Cursor {
        chars: text.trim().chars().collect(),
        at: 0,
    };
    p.expect('{')?;
    let (mut descr, mut fortran, mut shape) = (None, None, None);
    loop {
        p.skip_space();
        if p.eat('}') {
            break;
        }
        let key = p.string()?;
        p.skip_space();
        p.expect(':')?;
        p.skip_space();
        let value = p.literal()?;
        match (key.as_str(), value) {
            ("descr", Literal::Str(s)) => descr = Some(s),
            ("fortran_order", Literal::Bool(b)) => fortran = Some(b),
            ("shape", Literal::Tuple(t)) => shape = Some(t),
            (k @ ("descr" | "fortran_order" | "shape"), v) => {
                return Err(format!("'{k}' has an unexpected value {v:?}"));
            }
            (other, _) => return Err(format!("unexpected key '{other}'")),
        }
        p.skip_space();
        if !p.eat(',') {
            p.skip_space();
            p.expect('}')?;
            break;
        }
    }
    let descr = descr.ok_or("no 'descr'")?;
    let dtype = match descr.as_str() {
        "<f8" => Dtype::F8,
        "<f4" => Dtype::F4,
        d if d.starts_with('>') => {
            return Err(format!(
                "dtype '{d}' is big-endian; only little-endian '<f8' and '<f4' are read"
            ));
        }
        d => {
            return Err(format!(
                "dtype '{d}' is not supported (only '<f8' and '<f4')"
            ));
        }
    };
    Ok(Header {
        dtype,
        fortran_order: fortran.ok_or("no 'fortran_order'")?,
        shape: shape.ok_or("no 'shape'")?,
    })
}

/// A character cursor over the header text.
struct Cursor {
    chars: Vec<char>,
    at: usize,
}

impl Cursor {
    fn peek(&self) -> Option<char> {
        self.chars.get(self.at).copied()
    }
    fn skip_space(&mut self) {
        while self.peek().is_some_and(char::is_whitespace) {
            self.at += 1;
        }
    }
    fn eat(&mut self, c: char) -> bool {
        let hit = self.peek() == Some(c);
        if hit {
            self.at += 1;
        }
        hit
    }
    fn expect(&mut self, c: char) -> std::result::Result<(), String> {
        if self.eat(c) {
            Ok(())
        } else {
            Err(format!("expected '{c}' at character {}", self.at))
        }
    }
    fn string(&mut self) -> std::result::Result<String, String> {
        let quote = self.peek().filter(|&q| q == '\'' || q == '"');
        let quote =
            quote.ok_or_else(|| format!("expected a quoted string at character {}", self.at))?;
        self.at += 1;
        let begin = self.at;
        while self.peek().is_some_and(|c| c != quote) {
            self.at += 1;
        }
        let s: String = self.chars[begin..self.at].iter().collect();
        self.expect(quote)?;
        Ok(s)
    }
    fn word(&mut self) -> String {
        let begin = self.at;
        while self
            .peek()
            .is_some_and(|c| c.is_ascii_alphanumeric() || c == '_')
        {
            self.at += 1;
        }
        self.chars[begin..self.at].iter().collect()
    }
    fn literal(&mut self) -> std::result::Result<Literal, String> {
        match self.peek() {
            Some('\'' | '"') => Ok(Literal::Str(self.string()?)),
            Some('(') => {
                self.at += 1;
                let mut dims = Vec::new();
                loop {
                    self.skip_space();
                    if self.eat(')') {
                        break;
                    }
                    let w = self.word();
                    let d = w.trim_end_matches('L').parse::<usize>();
                    dims.push(d.map_err(|_| format!("shape entry {w:?} is not a size"))?);
                    self.skip_space();
                    if !self.eat(',') {
                        self.skip_space();
                        self.expect(')')?;
                        break;
                    }
                }
                Ok(Literal::Tuple(dims))
            }
            _ => match self.word().as_str() {
                "True" => Ok(Literal::Bool(true)),
                "False" => Ok(Literal::Bool(false)),
                w => Err(format!("unexpected value {w:?} at character {}", self.at)),
            },
        }
    }
}

/// Reorders column-major (Fortran) `values` of `shape` into row-major order.
fn fortran_to_c(values: &[f64], shape: &[usize]) -> Vec<f64> {
    let n = shape.len();
    // Fortran strides: the first index varies fastest.
    let mut strides = vec![1usize; n];
    for k in 1..n {
        strides[k] = strides[k - 1] * shape[k - 1];
    }
    let mut index = vec![0usize; n];
    let mut out = Vec::with_capacity(values.len());
    for _ in 0..values.len() {
        out.push(
            values[index
                .iter()
                .zip(&strides)
                .map(|(i, s)| i * s)
                .sum::<usize>()],
        );
        // Row-major walk: the last index varies fastest.
        for k in (0..n).rev() {
            index[k] += 1;
            if index[k] < shape[k] {
                break;
            }
            index[k] = 0;
        }
    }
    out
}

/// Encodes a row-major array as a `.npy` (v1 header unless `v2`), for tests and small outputs.
/// `descr` is written as given so that tests can also produce files this reader rejects.
#[cfg(test)]
pub(crate) fn encode_npy(
    shape: &[usize],
    body: &[u8],
    descr: &str,
    fortran: bool,
    v2: bool,
) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let dims = if shape.len() == 1 {
        format!("{},", dims[0])
    } else {
        dims.join(", ")
    };
    let order = if fortran { "True" } else { "False" };
    let mut header =
        format!("{{'descr': '{descr}', 'fortran_order': {order}, 'shape': ({dims}), }}");
    let prefix = if v2 { 12 } else { 10 };
    // Pad with spaces so that the data starts on a 64-byte boundary, ending in '\n'.
    while (prefix + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = MAGIC.to_vec();
    if v2 {
        out.extend([2, 0]);
        out.extend((header.len() as u32).to_le_bytes());
    } else {
        out.extend([1, 0]);
        out.extend((header.len() as u16).to_le_bytes());
    }
    out.extend(header.bytes());
    out.extend(body);
    out
}

/// The little-endian bytes of `values` as `<f8`.
#[cfg(test)]
pub(crate) fn f8_bytes(values: &[f64]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

#[cfg(test)]
mod tests;
