//! hapticctrl's Python package, native part: the bindings of
//! `virtuose_api` (module `hapticctrl._native`, feature `python`, built by
//! maturin) and, for their tests, the fake controller behind the bridge's
//! authentication gate ([`fake`], binary `hapticctrl-fake`).

pub mod fake;
pub mod pacing;

#[cfg(feature = "python")]
mod python;
