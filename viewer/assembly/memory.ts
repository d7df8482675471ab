// Element access to the arrays callers lay out in linear memory (byte offsets), for march.ts
// and hashgrid.ts.

@inline export function f32At(p: usize, i: i32): f32 { return load<f32>(p + (<usize>i << 2)); }
@inline export function i32At(p: usize, i: i32): i32 { return load<i32>(p + (<usize>i << 2)); }
@inline export function f64At(p: usize, i: i32): f64 { return load<f64>(p + (<usize>i << 3)); }
@inline export function setF32(p: usize, i: i32, v: f32): void { store<f32>(p + (<usize>i << 2), v); }
@inline export function setI32(p: usize, i: i32, v: i32): void { store<i32>(p + (<usize>i << 2), v); }
