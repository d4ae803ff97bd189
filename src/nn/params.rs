//! Parameter store: every trainable tensor of a model lives in ONE flat f32 arena (as in llm.c),
//! addressed by a [`ParamId`]. Gradients and Adam moments are plain `Vec<f32>`s of the same length
//! with the same offsets, so the optimizer and checkpoints walk one contiguous buffer.

use std::ops::Range;

/// Name and shape of one tensor (shapes follow the Keras weight layout so checkpoints line up).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ParamSpec {
    pub name: String,
    pub shape: Vec<usize>,
}

/// Handle of a tensor in a [`Params`] (its index in insertion order).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ParamId(usize);

#[derive(Clone, Debug, PartialEq)]
struct Entry {
    spec: ParamSpec,
    range: Range<usize>,
}

/// All parameters of a model: specs and offsets plus the arena of values.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Params {
    entries: Vec<Entry>,
    pub values: Vec<f32>,
}

impl Params {
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends a zero tensor. Panics on a duplicate name (a programming error in a model definition).
    pub fn add(&mut self, name: &str, shape: &[usize]) -> ParamId {
        assert!(self.find(name).is_none(), "duplicate parameter name `{name}`");
        let spec = ParamSpec { name: name.to_string(), shape: shape.to_vec() };
        // Offsets come from the specs, not from `values.len()`, which is public and could be resized.
        let start = self.entries.last().map_or(0, |e| e.range.end);
        // A shape `[]` is a scalar (product of no dims = 1).
        let range = start..start + spec.shape.iter().product::<usize>();
        self.values.resize(range.end, 0.0);
        self.entries.push(Entry { spec, range });
        ParamId(self.entries.len() - 1)
    }

    /// Total number of scalars.
    pub fn len(&self) -> usize {
        self.entries.last().map_or(0, |e| e.range.end)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Every tensor in insertion (= arena) order.
    pub fn specs(&self) -> impl Iterator<Item = (ParamId, &ParamSpec)> {
        self.entries.iter().enumerate().map(|(i, e)| (ParamId(i), &e.spec))
    }

    pub fn spec(&self, id: ParamId) -> &ParamSpec {
        &self.entries[id.0].spec
    }

    /// Linear scan: lookups happen when a model is built, not in the hot path.
    pub fn find(&self, name: &str) -> Option<ParamId> {
        self.entries.iter().position(|e| e.spec.name == name).map(ParamId)
    }

    /// Offsets of the tensor in the arena (and in every buffer laid out like it).
    pub fn range(&self, id: ParamId) -> Range<usize> {
        self.entries[id.0].range.clone()
    }

    pub fn get(&self, id: ParamId) -> &[f32] {
        &self.values[self.range(id)]
    }

    pub fn get_mut(&mut self, id: ParamId) -> &mut [f32] {
        let r = self.range(id);
        &mut self.values[r]
    }

    /// The same tensor's slice of another buffer laid out like the arena (gradients, moments).
    pub fn of<'a>(&self, buf: &'a [f32], id: ParamId) -> &'a [f32] {
        self.check_len(buf.len());
        &buf[self.range(id)]
    }

    /// Two distinct tensors of a buffer mutably at once (a layer's dweight and dbias). Panics if a == b.
    pub fn pair_mut<'a>(&self, buf: &'a mut [f32], a: ParamId, b: ParamId) -> (&'a mut [f32], &'a mut [f32]) {
        assert_ne!(a, b, "pair_mut needs two distinct tensors");
        self.check_len(buf.len());
        let (ra, rb) = (self.range(a), self.range(b));
        // Distinct tensors occupy disjoint ranges, so splitting at the later start separates them.
        if ra.start < rb.start {
            let (lo, hi) = buf.split_at_mut(rb.start);
            (&mut lo[ra], &mut hi[..rb.len()])
        } else {
            let (lo, hi) = buf.split_at_mut(ra.start);
            (&mut hi[..ra.len()], &mut lo[rb])
        }
    }

    pub fn fill(&mut self, id: ParamId, value: f32) {
        self.get_mut(id).fill(value);
    }

    /// Uniform in [−limit, limit) from the given RNG (Glorot: limit = sqrt(6 / (fan_in + fan_out))).
    pub fn fill_uniform(&mut self, id: ParamId, limit: f32, rng: &mut impl rand::Rng) {
        assert!(limit.is_finite() && limit > 0.0, "fill_uniform: limit must be positive, got {limit}");
        let dist = rand::distr::Uniform::new(-limit, limit).expect("valid range checked above");
        for x in self.get_mut(id) {
            *x = rng.sample(dist);
        }
    }

    fn check_len(&self, len: usize) {
        assert_eq!(len, self.len(), "buffer is not laid out like the parameter arena");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn sample() -> (Params, ParamId, ParamId, ParamId) {
        let mut p = Params::new();
        let w = p.add("dense/kernel", &[3, 2]);
        let b = p.add("dense/bias", &[2]);
        let s = p.add("scale", &[]);
        (p, w, b, s)
    }

    #[test]
    fn add_find_get() {
        let (mut p, w, b, s) = sample();
        assert_eq!(p.len(), 9);
        assert!(!p.is_empty() && Params::new().is_empty());
        assert_eq!(p.values, vec![0.0; 9]);
        assert_eq!((p.range(w), p.range(b), p.range(s)), (0..6, 6..8, 8..9));
        assert_eq!(p.find("dense/bias"), Some(b));
        assert_eq!(p.find("nope"), None);
        assert_eq!(p.spec(w), &ParamSpec { name: "dense/kernel".into(), shape: vec![3, 2] });
        let names: Vec<_> = p.specs().map(|(id, s)| (id, s.name.as_str())).collect();
        assert_eq!(names, vec![(w, "dense/kernel"), (b, "dense/bias"), (s, "scale")]);

        p.fill(b, 2.5);
        p.get_mut(s)[0] = -1.0;
        assert_eq!(p.get(b), &[2.5, 2.5]);
        assert_eq!(p.get(s), &[-1.0]);
        assert_eq!(p.get(w), &[0.0; 6]);
    }

    #[test]
    #[should_panic(expected = "duplicate parameter name")]
    fn duplicate_name_panics() {
        let (mut p, ..) = sample();
        p.add("dense/bias", &[4]);
    }

    #[test]
    fn of_and_pair_mut() {
        let (p, w, b, s) = sample();
        let mut grad: Vec<f32> = (0..9).map(|i| i as f32).collect();
        assert_eq!(p.of(&grad, b), &[6.0, 7.0]);
        assert_eq!(p.of(&grad, s), &[8.0]);
        for (x, y) in [(w, b), (b, w)] {
            let (gx, gy) = p.pair_mut(&mut grad, x, y);
            assert_eq!((gx.len(), gy.len()), (p.range(x).len(), p.range(y).len()));
            gx[0] += 100.0;
            gy[0] += 1000.0;
        }
        assert_eq!(p.of(&grad, w)[0], 1100.0);
        assert_eq!(p.of(&grad, b)[0], 1106.0);
    }

    #[test]
    #[should_panic(expected = "distinct")]
    fn pair_mut_same_id_panics() {
        let (p, w, ..) = sample();
        let mut grad = vec![0.0; p.len()];
        let _ = p.pair_mut(&mut grad, w, w);
    }

    #[test]
    #[should_panic(expected = "laid out like")]
    fn of_wrong_length_panics() {
        let (p, w, ..) = sample();
        let _ = p.of(&[0.0; 3], w);
    }

    #[test]
    fn fill_uniform_in_range_and_reproducible() {
        let (mut p, w, b, _) = sample();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        p.fill_uniform(w, 0.5, &mut rng);
        assert!(p.get(w).iter().all(|&x| (-0.5..0.5).contains(&x)));
        assert!(p.get(w).iter().any(|&x| x != 0.0));
        assert_eq!(p.get(b), &[0.0, 0.0], "neighbours untouched");
        let mut q = sample().0;
        q.fill_uniform(w, 0.5, &mut rand_pcg::Pcg64::seed_from_u64(7));
        assert_eq!(p.get(w), q.get(w));
    }
}
