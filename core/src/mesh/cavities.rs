//! Which empty lattice nodes count as outside; the others are filled (counted as inside).
//!
//! A NeRF is free to leave the inside of an object hollow (no ray ever sees it), and marching
//! cubes then draws the hollow's wall too: a second, inward-facing shell inside each solid. A
//! flood fill from the border through open nodes (6-neighbours) finds every node the outside
//! reaches; the empty nodes it does not reach are filled, which leaves only the outer surface.
//!
//! Open nodes are the empty ones, or with visibility carving ([`super::carve`]) the empty ones
//! some camera sees as empty or none has in view, [`widen`]ed by a step into the hidden
//! ones beside them: a view sees a node empty only a margin in front of its surface, and the
//! empty nodes within that margin must stay open for the surface to fall between them and the
//! dense ones. Foam, hollows and pockets no camera sees are then walls, even where unseen space
//! joins them to the border. One bit per node for "dense" and one for "open" (then "reached"):
//! 2 · 1025³ bits (270 MB) at 1024 cells per axis.

use std::collections::VecDeque;

/// One bit per lattice node, node `(i, j, k)` at `(k·m + j)·m + i` with `m = n + 1`.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeBits {
    words: Vec<u64>,
}

impl NodeBits {
    /// All clear, for `len` nodes.
    pub fn new(len: usize) -> Self {
        NodeBits { words: vec![0; len.div_ceil(64)] }
    }

    /// Bit `i`.
    pub fn get(&self, i: usize) -> bool {
        self.words[i / 64] >> (i % 64) & 1 == 1
    }

    /// Set bit `i`.
    pub fn set(&mut self, i: usize) {
        self.words[i / 64] |= 1 << (i % 64);
    }

    /// Flip every bit (those past the length too; [`NodeBits::get`] never reads them).
    pub fn invert(&mut self) {
        for w in &mut self.words {
            *w = !*w;
        }
    }
}

/// Open the nodes of an `n`-cell lattice that are neither `dense` nor `open` but lie within
/// `steps` 6-neighbour steps of an open node through such nodes. Each step scans the bits once
/// and opens the nodes it found afterwards, so one step moves one node.
pub fn widen(n: usize, open: &mut NodeBits, dense: &NodeBits, steps: usize) {
    let m = n + 1;
    for _ in 0..steps {
        let mut found = Vec::new();
        for (w, (&o, &d)) in open.words.iter().zip(&dense.words).enumerate() {
            let mut closed = !o & !d;
            while closed != 0 {
                let at = w * 64 + closed.trailing_zeros() as usize;
                closed &= closed - 1;
                if at >= m * m * m {
                    break;
                }
                let (i, j, k) = (at % m, (at / m) % m, at / (m * m));
                let beside = [(1, i), (m, j), (m * m, k)].iter().any(|&(d, x)| (x > 0 && open.get(at - d)) || (x < n && open.get(at + d)));
                if beside {
                    found.push(at);
                }
            }
        }
        if found.is_empty() {
            break;
        }
        for at in found {
            open.set(at);
        }
    }
}

/// The nodes of an `n`-cell lattice that the border reaches through nodes not in `walls`
/// (the dense nodes, and with carving the hidden empty ones).
pub fn reached_from_border(n: usize, walls: &NodeBits) -> NodeBits {
    let m = n + 1;
    let mut reached = NodeBits::new(m * m * m);
    let mut queue = VecDeque::new();
    let visit = |i: usize, queue: &mut VecDeque<usize>, reached: &mut NodeBits| {
        if !walls.get(i) && !reached.get(i) {
            reached.set(i);
            queue.push_back(i);
        }
    };
    for k in 0..m {
        for j in 0..m {
            for i in 0..m {
                if [i, j, k].iter().any(|&x| x == 0 || x == n) {
                    visit((k * m + j) * m + i, &mut queue, &mut reached);
                }
            }
        }
    }
    while let Some(at) = queue.pop_front() {
        let (i, j, k) = (at % m, (at / m) % m, at / (m * m));
        for (d, x) in [(1, i), (m, j), (m * m, k)] {
            if x > 0 {
                visit(at - d, &mut queue, &mut reached);
            }
            if x < n {
                visit(at + d, &mut queue, &mut reached);
            }
        }
    }
    reached
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_hollow_cube_has_one_cavity_and_a_notch_does_not() {
        // 6 cells (7 nodes) per axis: a shell of dense nodes at 1 and 5 on every axis around
        // an empty 3³ hollow (nodes 2–4).
        let (n, m) = (6, 7);
        let index = |i: usize, j: usize, k: usize| (k * m + j) * m + i;
        let mut dense = NodeBits::new(m * m * m);
        for k in 1..=5 {
            for j in 1..=5 {
                for i in 1..=5 {
                    if [i, j, k].iter().any(|&x| x == 1 || x == 5) {
                        dense.set(index(i, j, k));
                    }
                }
            }
        }
        let reached = reached_from_border(n, &dense);
        let cavity = |r: &NodeBits, d: &NodeBits| (0..m * m * m).filter(|&x| !d.get(x) && !r.get(x)).count();
        assert_eq!(cavity(&reached, &dense), 27);
        assert!(reached.get(index(0, 3, 3)) && !reached.get(index(3, 3, 3)));
        // A hole in the shell (node (5, 3, 3) empty) opens the hollow: no cavity left.
        let mut open = NodeBits::new(m * m * m);
        for x in (0..m * m * m).filter(|&x| dense.get(x) && x != index(5, 3, 3)) {
            open.set(x);
        }
        assert_eq!(cavity(&reached_from_border(n, &open), &open), 0);
    }

    #[test]
    fn widening_opens_hidden_nodes_a_step_at_a_time_and_never_dense_ones() {
        // The hollow cube above with a hole at (5, 3, 3): every node outside the shell is open,
        // the hole and the 27 of the hollow are hidden.
        let (n, m) = (6, 7);
        let index = |i: usize, j: usize, k: usize| (k * m + j) * m + i;
        let (mut dense, mut open) = (NodeBits::new(m * m * m), NodeBits::new(m * m * m));
        for k in 0..m {
            for j in 0..m {
                for i in 0..m {
                    let at = index(i, j, k);
                    if [i, j, k].iter().any(|&x| x == 0 || x == 6) {
                        open.set(at);
                    } else if [i, j, k].iter().any(|&x| x == 1 || x == 5) && at != index(5, 3, 3) {
                        dense.set(at);
                    }
                }
            }
        }
        let hidden = |open: &NodeBits| (0..m * m * m).filter(|&x| !dense.get(x) && !open.get(x)).count();
        assert_eq!(hidden(&open), 28);
        widen(n, &mut open, &dense, 1);
        assert!(open.get(index(5, 3, 3)) && hidden(&open) == 27);
        widen(n, &mut open, &dense, 1);
        assert!(open.get(index(4, 3, 3)) && hidden(&open) == 26);
        widen(n, &mut open, &dense, 10);
        assert_eq!(hidden(&open), 0);
        assert!((0..m * m * m).all(|x| !(dense.get(x) && open.get(x))), "dense nodes stay shut");
        // Walls are the rest: with everything open but the dense nodes, the border reaches all.
        let mut walls = open.clone();
        walls.invert();
        let reached = reached_from_border(n, &walls);
        assert!((0..m * m * m).all(|x| reached.get(x) != dense.get(x)));
    }
}
