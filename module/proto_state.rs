// SPDX-License-Identifier: GPL-2.0

//! The protocol's state (`mtx_proto`: hap-core's `ProtoIn`, the VPr shared
//! memory) and its two lock-free publications.
//!
//! Protocol:
//! - `proto` (`mtx_proto`): PROTO_IN locks it for each frame; the
//!   fail-safe and rmmod lock it to close the session. SERVO and the
//!   devices never take it.
//! - `vpr_latch` (hap-core's `VprLatchRecord` under a seqcount): written
//!   only with the `mtx_proto` guard in hand ([`ProtoState::publish_vpr`]
//!   takes it as its witness), so its writers are serialised; SERVO reads
//!   it without any lock ([`ProtoState::latest_vpr`]).
//! - `publication` (hap-core's `ProtoPublication` under a seqcount): PROTO_IN
//!   writes it after each frame, also under `mtx_proto`; /dev/hap_stats
//!   reads it.
//!
//! Each publication's writer claims hap-core's `seqlock::Writer` role for
//! its write; all its writers hold the `mtx_proto` guard meanwhile, so the
//! role is always free when claimed.

use crate::{
    hap_core::{
        proto_in::{ProtoIn, ProtoPublication, PROTO_PUBLICATION_WORDS},
        seqlock::SeqWords,
        vp::{VpReceived, VprLatchRecord, VPR_LATCH_WORDS},
    },
    ring::Words,
};
use kernel::{
    new_mutex,
    prelude::*,
    sync::{Mutex, MutexGuard},
};

/// SERVO's read attempts of the VPr latch (a publication is
/// `VPR_LATCH_WORDS` = 20 word stores;
/// on one CPU a PROTO_IN preempted inside one does not finish meanwhile).
const VPR_READ_ATTEMPTS: usize = 4;

/// Read attempts of PROTO_IN's publication by /dev/hap_stats.
const PUBLICATION_READ_ATTEMPTS: usize = 1000;

#[pin_data]
pub(crate) struct ProtoState {
    #[pin]
    proto: Mutex<KBox<ProtoIn>>,
    vpr_latch: SeqWords<Words<VPR_LATCH_WORDS>>,
    publication: SeqWords<Words<PROTO_PUBLICATION_WORDS>>,
}

impl ProtoState {
    pub(crate) fn new() -> Result<impl PinInit<Self, Error>> {
        let proto = KBox::new(ProtoIn::new(), GFP_KERNEL)?;
        // The latch starts as the protocol does (no session, its initial VPr).
        let vpr_latch = SeqWords::new(Words::new());
        write_latch(&vpr_latch, &proto);
        Ok(try_pin_init!(Self {
            proto <- new_mutex!(proto),
            vpr_latch,
            publication: SeqWords::new(Words::new()),
        }? Error))
    }

    /// `mtx_proto`.
    pub(crate) fn lock(&self) -> MutexGuard<'_, KBox<ProtoIn>> {
        self.proto.lock()
    }

    /// Publish the protocol's session and VPr into the VPr latch; the
    /// `mtx_proto` guard serialises the latch's writers.
    pub(crate) fn publish_vpr(&self, proto: &MutexGuard<'_, KBox<ProtoIn>>) {
        write_latch(&self.vpr_latch, proto);
    }

    /// Publish PROTO_IN's counters and session (after each frame, under
    /// `mtx_proto`, whose guard serialises this publication's writers).
    pub(crate) fn publish_counters(&self, proto: &MutexGuard<'_, KBox<ProtoIn>>) {
        let mut p = ProtoPublication {
            counters: *proto.counters(),
            session: proto.session(),
        };
        // Free: every claim of it is made under `mtx_proto` (module doc).
        let Some(mut writer) = self.publication.claim_writer() else {
            return;
        };
        let w = writer.write();
        p.visit_words(|i, v| w.set(i, *v));
    }

    /// Close the protocol (the fail-safe, rmmod) and publish the closed
    /// session and VPr.
    pub(crate) fn close(&self) {
        let mut proto = self.proto.lock();
        proto.close();
        self.publish_vpr(&proto);
    }

    /// SERVO: the session and the VPr last published, without any lock;
    /// `None` if every attempt overlapped a publication (a PROTO_IN
    /// preempted inside its few stores: SERVO extrapolates).
    pub(crate) fn latest_vpr(&self) -> Option<(u16, VpReceived)> {
        let mut words = [0u64; VPR_LATCH_WORDS];
        self.vpr_latch.read(&mut words, VPR_READ_ATTEMPTS)?;
        let mut rec = VprLatchRecord::default();
        rec.visit_words(|i, v| {
            if let Some(w) = words.get(i) {
                *v = *w;
            }
        });
        Some((rec.session, rec.vpr))
    }

    /// PROTO_IN's published counters and session (zeroes if every read
    /// attempt overlapped a publication).
    pub(crate) fn publication(&self) -> ProtoPublication {
        let mut words = [0u64; PROTO_PUBLICATION_WORDS];
        let mut p = ProtoPublication::default();
        if self
            .publication
            .read(&mut words, PUBLICATION_READ_ATTEMPTS)
            .is_some()
        {
            p.visit_words(|i, v| {
                if let Some(w) = words.get(i) {
                    *v = *w;
                }
            });
        }
        p
    }
}

fn write_latch(latch: &SeqWords<Words<VPR_LATCH_WORDS>>, proto: &ProtoIn) {
    let mut rec = VprLatchRecord {
        session: proto.session(),
        vpr: *proto.vpr(),
    };
    // Free: every claim of it is made under `mtx_proto`, or in `new`
    // before the latch is shared (module doc).
    let Some(mut writer) = latch.claim_writer() else {
        return;
    };
    let w = writer.write();
    rec.visit_words(|i, v| w.set(i, *v));
}
