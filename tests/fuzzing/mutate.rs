//! The mutator: byte-level mutations of any file, tree mutations of JSON and TOML documents,
//! and message mutations of ONNX graphs. Everything draws from one seeded [`Rng`], so a seed
//! reproduces the same inputs.

use nerf_core::Rng;
use nerf_export::proto::{ModelProto, tensor_shape_proto, type_proto};
use prost::Message;
use serde_json::Value;

/// How a harness's files are structured, which picks the structure-aware mutations.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// A JSON document (`transforms_*.json`, `camera.json`, `scene.json`, `state.json`).
    Json,
    /// A TOML document (`config.toml`).
    Toml,
    /// An ONNX protobuf (`coarse.onnx`).
    Onnx,
    /// Anything else (images, `occupancy.bin`, burnpack files).
    Binary,
}

/// One fuzz input: a seed changed by 1–8 stacked mutations, or (1 in 25) random bytes.
pub fn mutate(rng: &mut Rng, seeds: &[Vec<u8>], format: Format) -> Vec<u8> {
    if rng.below(25) == 0 {
        let len = [0, 1, 8, 64, 1024][rng.below(5)];
        return random_bytes(rng, len);
    }
    let mut data = seeds[rng.below(seeds.len())].clone();
    // Mostly few mutations (a file close to a valid one gets deep into the parser), sometimes many.
    let count = 1 + rng.below(2) + rng.below(2) * rng.below(7);
    for _ in 0..count {
        let structured = format != Format::Binary && rng.below(2) == 0;
        let done = structured
            && match format {
                Format::Json => mutate_json_text(rng, &data).map(|d| data = d).is_some(),
                Format::Toml => mutate_toml_text(rng, &data).map(|d| data = d).is_some(),
                Format::Onnx => mutate_onnx(rng, &data).map(|d| data = d).is_some(),
                Format::Binary => false,
            };
        if !done {
            mutate_bytes(rng, &mut data, seeds);
        }
    }
    data
}

fn random_bytes(rng: &mut Rng, len: usize) -> Vec<u8> {
    (0..len).map(|_| rng.next_u32() as u8).collect()
}

fn pick<T: Clone>(rng: &mut Rng, items: &[T]) -> T {
    items[rng.below(items.len())].clone()
}

/// Bytes that change the meaning of text formats, plus the extremes.
const INTERESTING_BYTES: [u8; 14] = [0, 1, 0x7f, 0x80, 0xff, b'"', b'{', b'[', b'0', b'-', b'.', b'\\', b'\n', b'e'];

/// Integers that hit limits: zero, ±1, powers of two at type edges, sizes that overflow products.
const INTERESTING_INTS: [i64; 16] = [
    0,
    1,
    -1,
    16,
    255,
    256,
    65535,
    65536,
    i32::MAX as i64,
    1 << 31,
    u32::MAX as i64,
    1 << 32,
    1 << 40,
    1 << 62,
    i64::MAX,
    i64::MIN,
];

/// Numbers as text (for JSON, TOML and any digits inside binary files).
const INTERESTING_NUMBERS: [&str; 22] = [
    "0",
    "-0",
    "-1",
    "1",
    "2147483647",
    "2147483648",
    "4294967295",
    "4294967296",
    "9223372036854775807",
    "18446744073709551615",
    "18446744073709551616",
    "99999999999999999999999999",
    "1e38",
    "3.5e38",
    "1e308",
    "1e999",
    "-1e999",
    "1e-45",
    "1e-400",
    "0.5",
    "NaN",
    "inf",
];

/// Strings a file path or name field should survive: traversal, absolute paths, device files,
/// empty, control characters, a very long name.
fn interesting_string(rng: &mut Rng) -> String {
    match rng.below(14) {
        0 => String::new(),
        1 => "..".into(),
        2 => "../../../../../../etc/passwd".into(),
        3 => "/".into(),
        4 => "/dev/zero".into(),
        5 => "/dev/urandom".into(),
        6 => "/proc/self/mem".into(),
        7 => ".".into(),
        8 => "./train/../../outside".into(),
        9 => "a".repeat(5000),
        10 => "\u{0}\u{1}\n".into(),
        11 => "ü€😀".into(),
        12 => "nerf-rs-scene-2".into(),
        _ => "checkpoints".into(),
    }
}

/// A byte-level mutation in place (`seeds` for splicing).
pub fn mutate_bytes(rng: &mut Rng, data: &mut Vec<u8>, seeds: &[Vec<u8>]) {
    let len = data.len();
    // A third of the time within the first 32 bytes, where binary formats keep their headers.
    let at = |rng: &mut Rng| if rng.below(3) == 0 { rng.below(len.clamp(1, 32)) } else { rng.below(len.max(1)) };
    match rng.below(11) {
        0 if len > 0 => {
            let i = at(rng);
            data[i] ^= 1 << rng.below(8);
        }
        1 if len > 0 => {
            let i = at(rng);
            data[i] = pick(rng, &INTERESTING_BYTES);
        }
        2 => {
            let i = rng.below(len + 1);
            let n = 1 + rng.below(16);
            let bytes = random_bytes(rng, n);
            data.splice(i..i, bytes);
        }
        3 if len > 0 => {
            let i = at(rng);
            let longest = if rng.below(4) == 0 { len } else { 64 };
            let n = 1 + rng.below((len - i).min(longest));
            data.drain(i..i + n);
        }
        4 => data.truncate(rng.below(len + 1)),
        5 if len > 0 => {
            // Duplicate a chunk, sometimes many times (long arrays, repeated records).
            let a = at(rng);
            let b = (a + 1 + rng.below(256)).min(len);
            let chunk = data[a..b].to_vec();
            let times = if rng.below(8) == 0 { 1 + rng.below(64) } else { 1 };
            let c = rng.below(len + 1);
            data.splice(c..c, chunk.iter().copied().cycle().take(chunk.len() * times));
        }
        6 => {
            // Splice: a prefix of this input with the rest of another seed.
            let other = &seeds[rng.below(seeds.len())];
            let cut = rng.below(len + 1);
            let from = rng.below(other.len() + 1);
            data.truncate(cut);
            data.extend_from_slice(&other[from..]);
        }
        7 if len > 0 => {
            let v = pick(rng, &INTERESTING_INTS);
            let width = pick(rng, &[1usize, 2, 4, 8]);
            // The low `width` bytes of `v`, little- or big-endian.
            let bytes = if rng.below(2) == 0 { v.to_le_bytes()[..width].to_vec() } else { v.to_be_bytes()[8 - width..].to_vec() };
            let i = at(rng);
            let end = (i + width).min(len);
            data[i..end].copy_from_slice(&bytes[..end - i]);
        }
        8 if len > 0 => {
            // An f32 special value at an aligned offset (binary headers and weights).
            let v = pick(rng, &[f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 0.0, -0.0, f32::MAX, f32::MIN_POSITIVE, 1e-45]);
            let i = at(rng) & !3;
            let end = (i + 4).min(len);
            data[i..end].copy_from_slice(&v.to_le_bytes()[..end - i]);
        }
        9 => replace_text_number(rng, data),
        _ => replace_text_string(rng, data),
    }
}

/// Replaces one run of number characters that holds a digit with an interesting number.
fn replace_text_number(rng: &mut Rng, data: &mut Vec<u8>) {
    let is_num = |b: u8| b.is_ascii_digit() || matches!(b, b'.' | b'-' | b'+' | b'e' | b'E');
    let mut runs = Vec::new();
    let mut i = 0;
    while i < data.len() {
        if is_num(data[i]) {
            let start = i;
            while i < data.len() && is_num(data[i]) {
                i += 1;
            }
            if data[start..i].iter().any(u8::is_ascii_digit) {
                runs.push(start..i);
            }
        } else {
            i += 1;
        }
    }
    if runs.is_empty() {
        return;
    }
    let run = runs[rng.below(runs.len())].clone();
    data.splice(run, pick(rng, &INTERESTING_NUMBERS).bytes());
}

/// Replaces the contents of one double-quoted string with an interesting string.
fn replace_text_string(rng: &mut Rng, data: &mut Vec<u8>) {
    let quotes: Vec<usize> = data.iter().enumerate().filter(|(_, b)| **b == b'"').map(|(i, _)| i).collect();
    if quotes.len() < 2 {
        return;
    }
    let k = rng.below(quotes.len() / 2) * 2;
    let (a, b) = (quotes[k] + 1, quotes[k + 1]);
    let s = interesting_string(rng);
    // Escaped for JSON so the document stays parseable and the value reaches the parser.
    let escaped = serde_json::to_string(&s).expect("a string serialises");
    data.splice(a..b, escaped[1..escaped.len() - 1].bytes());
}

/// Placeholders for values a `serde_json::Value` cannot hold, swapped in after serialising.
const SPECIAL_FLOATS: [(&str, &str, &str); 3] =
    [("__fuzz_nan__", "NaN", "nan"), ("__fuzz_inf__", "1e999", "inf"), ("__fuzz_ninf__", "-1e999", "-inf")];

/// A tree mutation of a JSON document, or `None` when `data` is not JSON.
pub fn mutate_json_text(rng: &mut Rng, data: &[u8]) -> Option<Vec<u8>> {
    let mut value: Value = serde_json::from_slice(data).ok()?;
    mutate_tree(rng, &mut value);
    let mut text = if rng.below(2) == 0 { serde_json::to_string(&value) } else { serde_json::to_string_pretty(&value) }.ok()?;
    for (placeholder, json, _) in SPECIAL_FLOATS {
        text = text.replace(&format!("\"{placeholder}\""), json);
    }
    for depth in NESTING_DEPTHS {
        text = text.replace(&format!("\"{}\"", nested_placeholder(depth)), &format!("{}{}", "[".repeat(depth), "]".repeat(depth)));
    }
    Some(text.into_bytes())
}

/// Depths of the nested arrays a node may become: around serde_json's recursion limit (128)
/// and far past it (a recursive parser would overflow its stack).
const NESTING_DEPTHS: [usize; 5] = [2, 127, 128, 1000, 100_000];

/// The placeholder for `depth` nested empty arrays, swapped in after serialising (a tree that
/// deep would overflow the serialiser's stack).
fn nested_placeholder(depth: usize) -> String {
    format!("__fuzz_nested_{depth}__")
}

/// A tree mutation of a TOML document (through the same tree as JSON), or `None` when `data`
/// is not TOML or the mutated tree has no TOML form (a null).
pub fn mutate_toml_text(rng: &mut Rng, data: &[u8]) -> Option<Vec<u8>> {
    let table: toml::Table = toml::from_str(std::str::from_utf8(data).ok()?).ok()?;
    let mut value = serde_json::to_value(&table).ok()?;
    mutate_tree(rng, &mut value);
    let table: toml::Table = serde_json::from_value(value).ok()?;
    let mut text = toml::to_string(&table).ok()?;
    for (placeholder, _, toml) in SPECIAL_FLOATS {
        text = text.replace(&format!("\"{placeholder}\""), toml);
    }
    Some(text.into_bytes())
}

/// JSON pointers of every node below the root.
fn node_pointers(value: &Value, at: String, out: &mut Vec<String>) {
    match value {
        Value::Object(map) => {
            for (k, v) in map {
                let p = format!("{at}/{}", k.replace('~', "~0").replace('/', "~1"));
                out.push(p.clone());
                node_pointers(v, p, out);
            }
        }
        Value::Array(items) => {
            for (i, v) in items.iter().enumerate() {
                let p = format!("{at}/{i}");
                out.push(p.clone());
                node_pointers(v, p, out);
            }
        }
        _ => {}
    }
}

fn interesting_number(rng: &mut Rng) -> Value {
    match rng.below(4) {
        0 => Value::from(pick(rng, &INTERESTING_INTS)),
        1 => Value::from(pick(rng, &[u64::MAX, 1 << 63, 1 << 53])),
        2 => Value::from(pick(rng, &[0.5, -0.0, 1e-45, 1e-300, 3.5e38, 1e38, 1e300, -1e300, 7.0e-3])),
        _ => Value::from(SPECIAL_FLOATS[rng.below(SPECIAL_FLOATS.len())].0),
    }
}

/// Replaces, nudges, retypes, removes or duplicates one node of the tree.
fn mutate_tree(rng: &mut Rng, root: &mut Value) {
    let mut pointers = Vec::new();
    node_pointers(root, String::new(), &mut pointers);
    if pointers.is_empty() {
        *root = interesting_number(rng);
        return;
    }
    let pointer = pointers[rng.below(pointers.len())].clone();
    let action = rng.below(8);
    if action == 0 {
        // Remove the node from its parent (a missing key, a shorter array).
        let (parent, last) = pointer.rsplit_once('/').expect("pointers start with /");
        match root.pointer_mut(parent) {
            Some(Value::Object(map)) => {
                map.remove(&last.replace("~1", "/").replace("~0", "~"));
            }
            Some(Value::Array(items)) => {
                items.remove(last.parse::<usize>().expect("array index"));
            }
            _ => {}
        }
        return;
    }
    let Some(node) = root.pointer_mut(&pointer) else { return };
    match action {
        1 => *node = interesting_number(rng),
        2 => *node = Value::from(interesting_string(rng)),
        3 => *node = pick(rng, &[Value::Null, Value::Bool(true), Value::Array(vec![]), Value::Object(Default::default()), Value::from("")]),
        7 => *node = Value::from(nested_placeholder(pick(rng, &NESTING_DEPTHS))),
        4 => {
            if let Some(x) = node.as_f64() {
                let y = pick(rng, &[x + 1.0, x - 1.0, -x, x * 1024.0, x / 1024.0, x.trunc()]);
                *node = if y.fract() == 0.0 && y.abs() < 9e15 { Value::from(y as i64) } else { Value::from(y) };
            } else {
                *node = interesting_number(rng);
            }
        }
        5 => {
            // Grow an array by copies of an element (many frames, long matrices).
            if let Value::Array(items) = node
                && !items.is_empty()
            {
                let copy = items[rng.below(items.len())].clone();
                let times = pick(rng, &[1, 2, 7, 100]);
                items.extend(std::iter::repeat_n(copy, times));
            } else {
                *node = Value::Array(vec![node.clone(), node.clone()]);
            }
        }
        _ => {
            // Shorten an array or string by one (a 4×3 matrix, a truncated name).
            match node {
                Value::Array(items) => {
                    items.pop();
                }
                Value::String(s) => {
                    s.pop();
                }
                other => *other = Value::Null,
            }
        }
    }
}

/// A mutation of an ONNX model's messages (metadata, initializers, inputs and outputs), or
/// `None` when `data` does not decode.
pub fn mutate_onnx(rng: &mut Rng, data: &[u8]) -> Option<Vec<u8>> {
    let mut model = ModelProto::decode(data).ok()?;
    match rng.below(6) {
        0 | 1 if !model.metadata_props.is_empty() => {
            // Most often the network description: sizes that must be checked before allocating.
            let json = model.metadata_props.iter().position(|p| p.key == "nerf.network");
            let k = json.filter(|_| rng.below(4) != 0).unwrap_or_else(|| rng.below(model.metadata_props.len()));
            let prop = &mut model.metadata_props[k];
            match rng.below(8) {
                0 => prop.key = interesting_string(rng),
                1 => {
                    model.metadata_props.remove(k);
                }
                _ => match mutate_json_text(rng, prop.value.as_bytes()) {
                    Some(v) => prop.value = String::from_utf8(v).ok()?,
                    None => prop.value = pick(rng, &INTERESTING_NUMBERS).into(),
                },
            }
        }
        2 => {
            let graph = model.graph.as_mut()?;
            if graph.initializer.is_empty() {
                return None;
            }
            let k = rng.below(graph.initializer.len());
            let t = &mut graph.initializer[k];
            match rng.below(8) {
                7 => {
                    // The data moved to another file (ONNX external data): the location flag,
                    // the entries naming the file, or both.
                    let entry = |key: &str, value: String| nerf_export::proto::StringStringEntryProto { key: key.into(), value };
                    if rng.below(3) != 0 {
                        t.data_location = 1;
                    }
                    if rng.below(3) != 0 {
                        t.external_data.push(entry("location", interesting_string(rng)));
                        t.external_data.push(entry("length", t.raw_data.len().to_string()));
                        t.raw_data.clear();
                    }
                }
                0 if !t.dims.is_empty() => {
                    let d = rng.below(t.dims.len());
                    t.dims[d] = pick(rng, &INTERESTING_INTS);
                }
                1 => t.dims.push(pick(rng, &[1, 0, -1, 3])),
                2 => {
                    t.dims.pop();
                }
                3 => t.data_type = rng.below(20) as i32,
                4 => {
                    let n = rng.below(t.raw_data.len() + 1);
                    t.raw_data.truncate(n);
                }
                5 => {
                    // The same values as float_data (the other valid encoding), sometimes one short.
                    t.float_data = t.raw_data.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
                    t.raw_data.clear();
                    if rng.below(2) == 0 {
                        t.float_data.pop();
                    }
                }
                _ => {
                    graph.initializer.remove(k);
                }
            }
        }
        3 => {
            let graph = model.graph.as_mut()?;
            let side = if rng.below(2) == 0 { &mut graph.input } else { &mut graph.output };
            if side.is_empty() {
                return None;
            }
            let k = rng.below(side.len());
            let v = &mut side[k];
            match rng.below(6) {
                0 => v.name = pick(rng, &["points", "viewdirs", "rgb", "sigma", "", "x"]).into(),
                1 => v.r#type = None,
                2 => {
                    side.remove(k);
                }
                _ => {
                    let Some(type_proto::Value::TensorType(t)) = v.r#type.as_mut().and_then(|t| t.value.as_mut()) else { return None };
                    match rng.below(4) {
                        0 => t.elem_type = rng.below(20) as i32,
                        1 => t.shape = None,
                        _ => {
                            let shape = t.shape.as_mut()?;
                            if shape.dim.is_empty() || rng.below(4) == 0 {
                                shape.dim.push(Default::default());
                            } else {
                                let d = rng.below(shape.dim.len());
                                shape.dim[d].value = Some(tensor_shape_proto::dimension::Value::DimValue(pick(rng, &INTERESTING_INTS)));
                            }
                        }
                    }
                }
            }
        }
        4 => model.graph = None,
        _ => {
            let graph = model.graph.as_mut()?;
            if graph.node.is_empty() {
                return None;
            }
            let k = rng.below(graph.node.len());
            graph.node.remove(k);
        }
    }
    Some(model.encode_to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_same_seed_makes_the_same_inputs() {
        let seeds = vec![br#"{"a": [1, 2.5, "x"], "b": {"c": true}}"#.to_vec()];
        let run = |seed| {
            let mut rng = Rng::new(seed);
            (0..200).map(|_| mutate(&mut rng, &seeds, Format::Json)).collect::<Vec<_>>()
        };
        assert_eq!(run(3), run(3));
        assert_ne!(run(3), run(4));
    }
}
