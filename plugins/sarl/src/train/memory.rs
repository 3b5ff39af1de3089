//! The replay memory of (joint state, value target) pairs.

use crate::state::JOINT_DIM;
use tch::Tensor;

/// A ring buffer of (joint states, value target) pairs, all with the same number of humans.
#[derive(Clone, Debug, PartialEq)]
pub struct Memory {
    pub(super) capacity: usize,
    pub(super) stride: usize,
    pub(super) states: Vec<f32>,
    pub(super) values: Vec<f32>,
    pub(super) next: usize,
}

impl Memory {
    /// An empty memory for states of `humans` humans.
    pub fn new(capacity: usize, humans: usize) -> Self {
        Self {
            capacity,
            stride: humans * JOINT_DIM,
            states: Vec::new(),
            values: Vec::new(),
            next: 0,
        }
    }

    /// Stored pairs.
    pub fn len(&self) -> usize {
        self.values.len()
    }

    /// True when nothing is stored.
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// Adds a pair, overwriting the oldest when full.
    pub fn push(&mut self, state: &[f32], value: f32) {
        debug_assert_eq!(state.len(), self.stride);
        if self.values.len() < self.capacity {
            self.states.extend_from_slice(state);
            self.values.push(value);
        } else {
            let i = self.next;
            self.states[i * self.stride..(i + 1) * self.stride].copy_from_slice(state);
            self.values[i] = value;
        }
        self.next = (self.next + 1) % self.capacity;
    }

    /// The batch at `indices`: states `[B, N, 13]` and values `[B, 1]`.
    pub(super) fn batch(&self, indices: &[usize]) -> (Tensor, Tensor) {
        let mut s = Vec::with_capacity(indices.len() * self.stride);
        let mut v = Vec::with_capacity(indices.len());
        for &i in indices {
            s.extend_from_slice(&self.states[i * self.stride..(i + 1) * self.stride]);
            v.push(self.values[i]);
        }
        let b = indices.len() as i64;
        (
            Tensor::from_slice(&s).reshape([b, (self.stride / JOINT_DIM) as i64, JOINT_DIM as i64]),
            Tensor::from_slice(&v).reshape([b, 1]),
        )
    }
}
