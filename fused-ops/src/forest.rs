//! `ai.haptics:ForestStep`: train's random forest (`rf`: sklearn_models.py `ForestModel`, a
//! `RandomForestRegressor`) as one node: the mean over the trees of each tree's leaf.
//!
//! Contract (docs/model-contract.md, stateless): input `features` [N, n], output `force`
//! [N, 1], any N.
//!
//! Why: skl2onnx's graph (`TreeEnsembleRegressor` + `Cast`) costs about 3.2 us over the
//! identity graph for 100 trees of ~1,000 nodes (docs/infer-server.md, "Every model family"),
//! and its layout takes 2-4 MB, so after any preemption most of the ~1,500 nodes a row visits
//! are cache misses. Here the forest is laid out once, at kernel creation:
//! - one 8-byte record per node ([`Node`]: the f32 threshold, the feature in the low 8 bits
//!   and the right child in the high 24), the nodes of each tree in depth-first order so the
//!   left child is the next record (no index stored) and a visited path is mostly ascending
//!   addresses: 100 trees of 1,000 nodes take 800 KB;
//! - a leaf is a record whose feature is the extra slot n of the row (always NaN: `NaN <= t`
//!   is false, so it "goes right" to itself) and whose threshold holds its value already
//!   divided by the number of trees (the mean folded in). A walk therefore needs no test for
//!   "is this a leaf": every tree takes exactly its depth's steps, each one a load, a compare
//!   and a conditional move (`select_unpredictable`: with a branch instead, rows off the path
//!   of the row before mispredict half the steps: 4.1 us a row instead of 0.7 for 100 trees
//!   of depth 9, examples/forest_cost.rs);
//! - [`LANES`] trees walk together (interleaved), so the loads of one tree's next node
//!   overlap with the others' instead of each step waiting for the previous load (16: 0.64
//!   us a row where 8 take 0.70 and 32 take 1.15, the example's warm rows).
//!
//! Semantics as scikit-learn's: the features as float32 (`ForestModel` fits and predicts on
//! float32 rows), `x <= threshold` goes left. scikit-learn's thresholds are float64 and it
//! compares the float32 feature widened to float64; the exporter writes each threshold rounded
//! DOWN to float32 (the largest float32 <= the float64 threshold), for which `x <= t32` holds
//! exactly when `x <= t64` for every float32 x: the same branch on every row, not just within
//! a tolerance. A NaN feature goes right at every split (scikit-learn without missing values
//! in training sends it to the larger child; the loop never sends NaN).
//!
//! Attributes (sklearn_models.py `forest_fused` writes them from each tree's `tree_`, the
//! trees one after the other): `n_features` INTS [1]; `tree_sizes` INTS [T] (nodes per tree);
//! `children_left`, `children_right` INTS [sum of sizes] (tree-local node indices, -1 for
//! both at a leaf); `split_features` INTS (the feature of each split, ignored at a leaf);
//! `thresholds` FLOATS (ignored at a leaf); `leaf_values` FLOATS (the node's value, read at
//! the leaves). Checked once: every index in range, every tree a tree (each node reached once
//! from its root, so every walk ends at a leaf), every value finite.

use crate::attrs::{AttrError, Attrs, Reader};
use crate::huge::HugeArray;
use crate::math::{self, Madd};
use crate::stateless::{RowModel, StatelessStep};

const OP: &str = "ForestStep";

/// Trees walked together.
pub const LANES: usize = 16;

/// The feature field's width in a node's link: at most 255 features (slot n is the leaves').
const FEATURE_BITS: u32 = 8;
const FEATURE_MASK: u32 = (1 << FEATURE_BITS) - 1;
/// At most 2^24 - 1 nodes in all (the right child's field).
const MAX_NODES: usize = (1 << (32 - FEATURE_BITS)) - 1;

/// One node: 8 bytes.
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C)]
struct Node {
    /// a split's threshold (float32, rounded down by the exporter); a leaf's value / trees
    t: f32,
    /// right child (global index) << 8 | feature (n at a leaf, whose right child is itself)
    link: u32,
}

/// [`LANES`] trees walked together: their roots and the steps that reach each one's deepest
/// leaf.
#[derive(Debug, Clone, PartialEq)]
struct Group {
    roots: [u32; LANES],
    steps: u32,
}

/// The forest, laid out once from the node's attributes.
#[derive(Debug, Clone, PartialEq)]
pub struct ForestParams {
    n: usize,
    /// in a huge page where the system gives one (huge.rs: one TLB entry, not hundreds)
    nodes: HugeArray<Node>,
    groups: Vec<Group>,
    /// the row as the walk reads it: the n features, then NaN (the leaves' slot), the rest
    /// unused (a feature index is 8 bits: any index reads inside it, no bounds check)
    row: [f32; 256],
    trees: usize,
}

/// One tree's nodes as the attributes give them (tree-local indices).
struct Tree<'a> {
    left: &'a [i64],
    right: &'a [i64],
    feature: &'a [i64],
    threshold: &'a [f64],
    value: &'a [f64],
}

impl ForestParams {
    /// Reads, checks and lays out the attributes.
    fn read<A: Attrs + ?Sized>(attrs: &A) -> Result<Self, AttrError> {
        let r = Reader { op: OP, attrs };
        let n = match r.sizes("n_features")?[..] {
            [n] => n,
            ref v => {
                return Err(r.invalid("n_features", v.len() as f64, "a count of values, not 1"))
            }
        };
        if n > FEATURE_MASK as usize - 1 {
            return Err(r.invalid(
                "n_features",
                n as f64,
                "over 254 (the nodes' 8-bit feature field)",
            ));
        }
        let sizes = r.sizes("tree_sizes")?;
        let total: usize = sizes.iter().sum();
        if total > MAX_NODES - LANES {
            return Err(r.invalid(
                "tree_sizes",
                total as f64,
                "a node count over 2^24 - 9 (the nodes' 24-bit child field)",
            ));
        }
        let left = r.ints_of("children_left", total, "the sum of tree_sizes")?;
        let right = r.ints_of("children_right", total, "the sum of tree_sizes")?;
        let feature = r.ints_of("split_features", total, "the sum of tree_sizes")?;
        let threshold = r.list_of("thresholds", total, "the sum of tree_sizes")?;
        let value = r.list_of("leaf_values", total, "the sum of tree_sizes")?;

        let trees = sizes.len();
        if trees == 0 {
            return Err(r.invalid("tree_sizes", 0.0, "a count of trees: none"));
        }
        let mut nodes = Vec::with_capacity(total + 1);
        let mut roots = Vec::with_capacity(trees);
        let mut start = 0;
        for &size in &sizes {
            let end = start + size;
            let tree = Tree {
                left: &left[start..end],
                right: &right[start..end],
                feature: &feature[start..end],
                threshold: &threshold[start..end],
                value: &value[start..end],
            };
            let depth = lay_out(&r, &tree, start, n, trees, &mut nodes)?;
            roots.push((nodes.len() - size, depth));
            start = end;
        }
        // the lanes left over in the last group walk a leaf of value 0
        let pad = nodes.len();
        nodes.push(Node {
            t: 0.0,
            link: link(pad, n),
        });
        // trees of like depth together: a group takes its deepest tree's steps
        roots.sort_by_key(|&(_, depth)| std::cmp::Reverse(depth));
        let groups = roots
            .chunks(LANES)
            .map(|chunk| Group {
                roots: std::array::from_fn(|l| chunk.get(l).map_or(pad, |&(i, _)| i) as u32),
                steps: chunk[0].1,
            })
            .collect();
        let mut row = [0.0; 256];
        row[n] = f32::NAN;
        let nodes = HugeArray::copy_of(&nodes).ok_or_else(|| {
            r.invalid(
                "tree_sizes",
                total as f64,
                "a node count too large to allocate",
            )
        })?;
        Ok(Self {
            n,
            nodes,
            groups,
            row,
            trees,
        })
    }

    /// Reads, checks and lays out `attrs` (what the kernel does at its creation).
    pub fn from_attrs_checked<A: Attrs + ?Sized>(attrs: &A) -> Result<Self, AttrError> {
        Self::read(attrs)
    }

    /// One row's force, compiled for this CPU (AVX2 where it has it), as the kernel runs it.
    pub fn predict(&mut self, x: &[f32]) -> f32 {
        math::fast!(M => self.row::<M>(x))
    }

    /// The trees.
    pub fn trees(&self) -> usize {
        self.trees
    }

    /// The nodes laid out (every tree's, and one padding leaf).
    pub fn nodes(&self) -> usize {
        self.nodes.len()
    }

    /// The forest's own memory (the nodes), in bytes.
    pub fn bytes(&self) -> usize {
        self.nodes.len() * core::mem::size_of::<Node>()
    }
}

/// `right << 8 | feature`.
fn link(right: usize, feature: usize) -> u32 {
    ((right as u32) << FEATURE_BITS) | feature as u32
}

/// Appends one tree's nodes to `out` in depth-first order (left child first, so it is always
/// the next record) and returns the depth of its deepest leaf. `base`: the tree's first node
/// in the attributes (for the errors' indices).
fn lay_out<A: Attrs + ?Sized>(
    r: &Reader<'_, A>,
    t: &Tree<'_>,
    base: usize,
    n: usize,
    trees: usize,
    out: &mut Vec<Node>,
) -> Result<u32, AttrError> {
    let size = t.left.len();
    let mut seen = vec![false; size];
    let mut depth = 0;
    // (tree-local node, depth, the record whose right child it is)
    let mut stack: Vec<(usize, u32, Option<usize>)> = vec![(0, 0, None)];
    while let Some((j, d, parent)) = stack.pop() {
        let at = base + j;
        if std::mem::replace(&mut seen[j], true) {
            return Err(r.invalid(
                "children_left",
                at as f64,
                "the index of a node reached twice: not a tree",
            ));
        }
        let me = out.len();
        if let Some(p) = parent {
            out[p].link |= (me as u32) << FEATURE_BITS;
        }
        let (lj, rj) = (t.left[j], t.right[j]);
        if lj == -1 && rj == -1 {
            let v = t.value[j] / trees as f64;
            out.push(Node {
                t: v as f32,
                link: link(me, n),
            });
            depth = depth.max(d);
            continue;
        }
        let child = |c: i64, name: &'static str| {
            usize::try_from(c)
                .ok()
                .filter(|&c| c < size && c != j)
                .ok_or_else(|| {
                    r.invalid(
                        name,
                        at as f64,
                        "the index of a node whose child is outside its tree",
                    )
                })
        };
        let (lj, rj) = (child(lj, "children_left")?, child(rj, "children_right")?);
        let f = usize::try_from(t.feature[j])
            .ok()
            .filter(|&f| f < n)
            .ok_or_else(|| {
                r.invalid(
                    "split_features",
                    at as f64,
                    "the index of a node whose feature is not below n_features",
                )
            })?;
        out.push(Node {
            t: t.threshold[j] as f32,
            link: f as u32,
        });
        stack.push((rj, d + 1, Some(me)));
        stack.push((lj, d + 1, None));
    }
    if let Some(j) = seen.iter().position(|&s| !s) {
        return Err(r.invalid(
            "children_left",
            (base + j) as f64,
            "the index of a node no root reaches: not a tree",
        ));
    }
    Ok(depth)
}

impl RowModel for ForestParams {
    const OP: &'static str = OP;

    fn from_attrs<A: Attrs + ?Sized>(attrs: &A) -> Result<Self, AttrError> {
        Self::read(attrs)
    }

    fn inputs(&self) -> usize {
        self.n
    }

    /// The force of one row: the sum of the trees' (pre-divided) leaves. Allocates nothing;
    /// the only data-dependent branches are the loops' (a group's steps are fixed).
    #[inline(always)]
    fn row<M: Madd>(&mut self, x: &[f32]) -> f32 {
        self.row[..self.n].copy_from_slice(x);
        let (nodes, row) = (&self.nodes[..], &self.row);
        let mut acc = [0.0f64; LANES];
        for g in &self.groups {
            let mut at = g.roots;
            for _ in 0..g.steps {
                for i in &mut at {
                    let node = nodes[*i as usize];
                    let v = row[(node.link & FEATURE_MASK) as usize];
                    let right = node.link >> FEATURE_BITS;
                    // left (the next record) when v <= t, else right: a conditional move,
                    // not a branch (LLVM turns a plain select, even a masked xor, into a
                    // branch, which rows off the trained path mispredict half the time)
                    *i = std::hint::select_unpredictable(v <= node.t, *i + 1, right);
                }
            }
            for (a, &i) in acc.iter_mut().zip(&at) {
                *a += f64::from(nodes[i as usize].t);
            }
        }
        acc.iter().sum::<f64>() as f32
    }
}

/// The operator ONNX Runtime registers (`ai.haptics:ForestStep`).
pub type ForestStep = StatelessStep<ForestParams>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::attrs::tests::Map;

    /// Two trees over (x0, x1):
    /// tree A: x0 <= 0.5 ? (x1 <= -1 ? 10 : 20) : 30   (nodes 0: split, 1: split, 2, 3, 4 leaves)
    /// tree B: x1 <= 2 ? 4 : (x0 <= -3 ? 6 : 8), written with its right subtree FIRST in the
    /// node list (0: split, 1: split, 2, 3 leaves of node 1, 4: leaf), as a builder other than
    /// depth-first might: the layout must not assume the order.
    fn two_trees() -> Map {
        Map::of(&[
            ("n_features", vec![2.0]),
            ("tree_sizes", vec![5.0, 5.0]),
            (
                "children_left",
                vec![1.0, 2.0, -1.0, -1.0, -1.0, 4.0, 2.0, -1.0, -1.0, -1.0],
            ),
            (
                "children_right",
                vec![4.0, 3.0, -1.0, -1.0, -1.0, 1.0, 3.0, -1.0, -1.0, -1.0],
            ),
            (
                "split_features",
                vec![0.0, 1.0, -2.0, -2.0, -2.0, 1.0, 0.0, -2.0, -2.0, -2.0],
            ),
            (
                "thresholds",
                vec![0.5, -1.0, -2.0, -2.0, -2.0, 2.0, -3.0, -2.0, -2.0, -2.0],
            ),
            (
                "leaf_values",
                vec![0.0, 0.0, 10.0, 20.0, 30.0, 0.0, 0.0, 6.0, 8.0, 4.0],
            ),
        ])
    }

    fn predict(p: &mut ForestParams, x: [f32; 2]) -> f32 {
        p.predict(&x)
    }

    #[test]
    fn a_row_is_the_mean_of_the_leaves_worked_out_by_hand() {
        let mut p = ForestParams::from_attrs(&two_trees()).unwrap();
        assert_eq!((p.trees(), p.nodes(), p.bytes()), (2, 11, 88));
        // (x0, x1) -> A's leaf, B's leaf; the answer their mean
        let cases = [
            ([0.0, -2.0], 10.0, 4.0),
            ([0.5, -1.0], 10.0, 4.0), // both thresholds exactly: `<=` goes left
            ([0.5, 0.0], 20.0, 4.0),
            ([0.6, 2.0], 30.0, 4.0),
            ([0.6, 2.5], 30.0, 8.0),
            ([-3.0, 2.5], 20.0, 6.0), // x0 exactly at B's second threshold
            ([-3.5, 1e9], 20.0, 6.0),
            ([f32::INFINITY, f32::NEG_INFINITY], 30.0, 4.0),
        ];
        for (x, a, b) in cases {
            assert_eq!(predict(&mut p, x), (a + b) / 2.0, "{x:?}");
            assert_eq!(p.row::<math::Split>(&x), (a + b) / 2.0, "{x:?}");
        }
    }

    #[test]
    fn more_trees_than_lanes_fill_several_groups() {
        // tree A of two_trees repeated 2 LANES + 3 times (3 groups, the last padded): the mean
        // of equal trees is that tree's leaf
        let trees = 2 * LANES + 3;
        let mut m = Map::of(&[("n_features", vec![2.0])]);
        let a = two_trees();
        for key in [
            "children_left",
            "children_right",
            "split_features",
            "thresholds",
            "leaf_values",
        ] {
            m = m.with(key, a.0[key][..5].repeat(trees));
        }
        let mut p = ForestParams::from_attrs(&m.with("tree_sizes", vec![5.0; trees])).unwrap();
        assert_eq!(p.groups.len(), 3);
        for (x, want) in [([0.0, -2.0], 10.0), ([0.0, 0.0], 20.0), ([1.0, 0.0], 30.0)] {
            let got = predict(&mut p, x);
            assert!((got - want).abs() < 1e-5, "{x:?}: {got} vs {want}");
        }
    }

    #[test]
    fn a_bad_attribute_is_a_clear_error_not_a_panic() {
        let bad = |key: &'static str, at: usize, v: f32| {
            let mut m = two_trees();
            let mut vals = m.0[key].clone();
            vals[at] = v;
            m = m.with(key, vals);
            m
        };
        let cases = [
            (bad("children_left", 1, 7.0), "attribute `children_left` = 1 is the index of a node whose child is outside its tree"),
            (bad("children_right", 6, -1.0), "attribute `children_right` = 6 is the index of a node whose child is outside its tree"),
            (bad("children_right", 6, 1.0), "attribute `children_right` = 6 is the index of a node whose child is outside its tree"),
            (bad("children_left", 1, 0.0), "attribute `children_left` = 0 is the index of a node reached twice: not a tree"),
            (bad("children_left", 6, 4.0), "attribute `children_left` = 9 is the index of a node reached twice: not a tree"),
            (bad("split_features", 5, 2.0), "attribute `split_features` = 5 is the index of a node whose feature is not below n_features"),
            (bad("thresholds", 0, f32::NAN), "attribute `thresholds` = NaN is not finite"),
            (two_trees().with("leaf_values", vec![1.0; 9]), "attribute `leaf_values` has 9 values, `the sum of tree_sizes` has 10: they pair up"),
            (two_trees().with("tree_sizes", vec![5.0, 0.0]), "attribute `tree_sizes` = 0 is not a size (>= 1)"),
            (two_trees().with("n_features", vec![2.0, 2.0]), "attribute `n_features` = 2 is a count of values, not 1"),
        ];
        for (attrs, want) in cases {
            let err = ForestParams::from_attrs(&attrs).unwrap_err().to_string();
            assert_eq!(err, format!("ForestStep: {want}"));
        }
    }

    #[test]
    fn a_node_no_root_reaches_is_refused() {
        // tree A with a sixth node, a leaf nothing points to
        let mut m = two_trees().with("tree_sizes", vec![6.0, 5.0]);
        for (key, extra) in [
            ("children_left", -1.0),
            ("children_right", -1.0),
            ("split_features", -2.0),
            ("thresholds", 0.0),
            ("leaf_values", 99.0),
        ] {
            let mut v = m.0[key].clone();
            v.insert(5, extra);
            m = m.with(key, v);
        }
        let err = ForestParams::from_attrs(&m).unwrap_err().to_string();
        assert_eq!(err, "ForestStep: attribute `children_left` = 5 is the index of a node no root reaches: not a tree");
    }
}
