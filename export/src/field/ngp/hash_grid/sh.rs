//! The degree-4 spherical harmonics of view directions as ONNX operators.

use super::{f32_scalar, slice};
use crate::builder::Builder;
use nerf_core::field::ngp::spherical_harmonics::SH4_CONSTANTS;

/// The 16 spherical harmonics of unit directions `input [N, 3]` → `[N, 16]`, the operations of
/// [`nerf_core::field::ngp::spherical_harmonics::sh4`] in the same order.
pub(crate) fn lower_sh4(g: &mut Builder, input: &str) -> String {
    let [x, y, z] = [0, 1, 2].map(|d| slice(g, input, (d, d + 1), 1, &format!("sh.{}", ["x", "y", "z"][d as usize])));
    let c: Vec<String> = SH4_CONSTANTS.iter().enumerate().map(|(i, &v)| f32_scalar(g, &format!("sh.c{i}"), v)).collect();
    let neg: Vec<String> = [1, 2].iter().map(|&i| f32_scalar(g, &format!("sh.neg_c{i}"), -SH4_CONSTANTS[i])).collect();
    let k = |g: &mut Builder, v: f32, name: &str| f32_scalar(g, name, v);
    let (m3, one, five, three) = (k(g, -3.0, "sh.minus3"), k(g, 1.0, "sh.one"), k(g, 5.0, "sh.five"), k(g, 3.0, "sh.three"));
    let mul = |g: &mut Builder, a: &str, b: &str, out: &str| g.node("Mul", &[a, b], &format!("sh.{out}"), vec![]);
    let xy = mul(g, &x, &y, "xy");
    let yz = mul(g, &y, &z, "yz");
    let xz = mul(g, &x, &z, "xz");
    let x2 = mul(g, &x, &x, "x2");
    let y2 = mul(g, &y, &y, "y2");
    let z2 = mul(g, &z, &z, "z2");
    // Band 0: the constant, one per row.
    let shape = g.node("Shape", &[&x], "sh.row_shape", vec![]);
    let c0 = g.node("Expand", &[&c[0], &shape], "sh.0", vec![]);
    let o1 = mul(g, &neg[0], &y, "1");
    let o2 = mul(g, &c[1], &z, "2");
    let o3 = mul(g, &neg[0], &x, "3");
    let o4 = mul(g, &c[2], &xy, "4");
    let o5 = mul(g, &neg[1], &yz, "5");
    let c3z2 = mul(g, &c[3], &z2, "c3z2");
    let o6 = g.node("Sub", &[&c3z2, &c[4]], "sh.6", vec![]);
    let o7 = mul(g, &neg[1], &xz, "7");
    let c5x2 = mul(g, &c[5], &x2, "c5x2");
    let c5y2 = mul(g, &c[5], &y2, "c5y2");
    let o8 = g.node("Sub", &[&c5x2, &c5y2], "sh.8", vec![]);
    // −3x² + y², 1 − 5z², 5z² − 3, x² − y², −x² + 3y².
    let m3x2 = mul(g, &m3, &x2, "m3x2");
    let p9 = g.node("Add", &[&m3x2, &y2], "sh.p9", vec![]);
    let five_z2 = mul(g, &five, &z2, "five_z2");
    let p11 = g.node("Sub", &[&one, &five_z2], "sh.p11", vec![]);
    let p12 = g.node("Sub", &[&five_z2, &three], "sh.p12", vec![]);
    let p14 = g.node("Sub", &[&x2, &y2], "sh.p14", vec![]);
    let neg_x2 = g.unary("Neg", &x2, "sh.neg_x2");
    let three_y2 = mul(g, &three, &y2, "three_y2");
    let p15 = g.node("Add", &[&neg_x2, &three_y2], "sh.p15", vec![]);
    let cxp = |g: &mut Builder, ci: usize, v: &str, p: &str, out: &str| {
        let cv = g.node("Mul", &[&c[ci], v], &format!("sh.c{ci}_{out}"), vec![]);
        g.node("Mul", &[&cv, p], &format!("sh.{out}"), vec![])
    };
    let o9 = cxp(g, 6, &y, &p9, "9");
    let o10 = cxp(g, 7, &xy, &z, "10");
    let o11 = cxp(g, 8, &y, &p11, "11");
    let o12 = cxp(g, 9, &z, &p12, "12");
    let o13 = cxp(g, 8, &x, &p11, "13");
    let o14 = cxp(g, 10, &z, &p14, "14");
    let o15 = cxp(g, 6, &x, &p15, "15");
    let all = [&c0, &o1, &o2, &o3, &o4, &o5, &o6, &o7, &o8, &o9, &o10, &o11, &o12, &o13, &o14, &o15];
    let all: Vec<&str> = all.iter().map(|s| s.as_str()).collect();
    g.concat(&all, nerf_bundle::ngp::SH_TENSOR)
}
