//! Disjoint sets over `0..n` as a parent array (`root[i] == i` at a set's root), for the
//! connected components the backends split a problem into: the conic backend's groups of bodies
//! coupled by contacts, Newton's independent blocks of a large `H` for the minimum-norm step.

/// The root of `i`'s set, halving the path as it goes.
pub(crate) fn find(root: &mut [usize], mut i: usize) -> usize {
    while root[i] != i {
        root[i] = root[root[i]];
        i = root[i];
    }
    i
}

/// Joins the sets of `a` and `b`; the smaller root becomes the root of both, so that every set's
/// root is its smallest element.
pub(crate) fn union(root: &mut [usize], a: usize, b: usize) {
    let (a, b) = (find(root, a), find(root, b));
    if a != b {
        root[a.max(b)] = a.min(b);
    }
}

#[cfg(test)]
mod tests {
    use super::{find, union};

    #[test]
    fn sets_are_rooted_at_their_smallest_element() {
        let mut root: Vec<usize> = (0..6).collect();
        union(&mut root, 4, 2);
        union(&mut root, 5, 4);
        union(&mut root, 3, 1);
        let roots: Vec<usize> = (0..6).map(|i| find(&mut root, i)).collect();
        assert_eq!(roots, [0, 1, 2, 1, 2, 2]);
    }
}
