//! The experiments of human2nav as a library, so that a program (the `human2nav` command-line
//! tool among them) runs them with a few calls and gets typed results back:
//!
//! * [`bench`](mod@bench): the closed-loop benchmark (suites × robots × methods) with its
//!   `results.csv`, `report.md` and figures, including the libtorch-backed `human2nav` method;
//! * [`train`]: training the conditional flow-matching model on the tuple cache and evaluating
//!   it on the held-out test scenes;
//! * [`scaling`]: the paper's Fig. 5, success rate against the amount of training data.
//!
//! Progress is drawn with the indicatif bars the caller passes in; outcomes are returned, and
//! printing them is the caller's business.

#![warn(missing_docs)]

pub mod bench;
pub mod scaling;
pub mod train;
