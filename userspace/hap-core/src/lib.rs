//! hap-core: the pure logic of hapticctrl.
//!
//! Everything that computes lives here once: the kernel module includes this
//! crate by source path (`#[path = ".../lib.rs"] mod hap_core;`) and the
//! userspace tools depend on it through cargo. Rules for every file:
//! - `no_std`, no dependencies, no allocation;
//! - no `f32`/`f64`/`i128` arithmetic outside `#[cfg(any(test, feature = "float"))]`
//!   (the kernel's soft-float and 128-bit helpers panic);
//! - never panic on input: saturate, or return a typed error.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]

pub mod arm;
pub mod arm_io;
pub mod clock;
pub mod config;
pub mod control;
pub mod crc;
pub mod cycle;
pub mod effort;
pub mod fixed;
pub mod handshake;
pub mod io;
pub mod link;
pub mod mode;
pub mod platform;
pub mod position_log;
pub mod proto_in;
pub mod proto_synchro;
pub mod protocol;
pub mod seqlock;
pub mod servo;
pub mod simulator;
pub mod spsc;
pub mod state_model;
pub mod stats;
pub mod vp;
pub mod words;
pub mod xdr;
