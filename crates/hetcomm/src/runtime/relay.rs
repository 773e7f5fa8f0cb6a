//! Unacknowledged sends on links with an intermediary that confirms frames (an MQTT broker's
//! PUBACK): the send's outcome waits for what the intermediary said (`hetcomm_link::relay`).

use super::*;
use hetcomm_link::relay::{RelayReceipt, RelayVerdict};
use hetcomm_router::FailReason;

impl SystemCore {
    /// Puts an unacknowledged send's frame on link `index`, asking the link for a receipt from
    /// its intermediary (frames reach it through [`SystemCore::leave`], which sends frames
    /// held back for batching, and frames a scheduled fault acts on, without one).
    pub(super) fn put_relayed_on_link(
        &self,
        index: usize,
        to: SystemId,
        frame: &[u8],
        body: &[u8],
    ) -> Result<Option<RelayReceipt>, TransmitError> {
        match self.links().get(index) {
            Some(link) => link
                .send_relayed(to, frame, body)
                .map_err(|e| transmit::transmit_error(&self.directory, e)),
            None => Err(TransmitError::Other("no such link".into())),
        }
    }

    /// Ends an unacknowledged send whose frame the link took with a receipt, in its ticket's
    /// `slot`: the outcome, reported as every outcome is ([`SystemCore::end_send`]), comes
    /// with the intermediary's verdict (on the link's thread, or at once if it is known
    /// already).
    pub(crate) fn end_relayed(
        &self,
        id: SendId,
        receipt: RelayReceipt,
        attempts: u32,
        transport: Option<&'static str>,
        slot: Arc<OutcomeSlot>,
    ) {
        let core = self.this.clone();
        receipt.then(move |verdict| {
            let outcome = relayed_outcome(verdict, attempts);
            match core.upgrade() {
                Some(core) => {
                    let now = core.clock.now();
                    core.end_send(id, outcome, transport, Some(slot), now);
                }
                None => slot.complete(outcome, transport),
            }
        });
    }
}

/// What the intermediary's verdict makes of a send whose frame the link took.
fn relayed_outcome(verdict: RelayVerdict, attempts: u32) -> Outcome {
    match verdict {
        RelayVerdict::Confirmed => Outcome::Relayed { attempts },
        RelayVerdict::Refused(why) => Outcome::Failed {
            reason: FailReason::Relay(why),
            attempts,
        },
        RelayVerdict::Unanswered(why) => Outcome::Unconfirmed {
            reason: FailReason::Relay(why),
            attempts,
        },
        RelayVerdict::Left => Outcome::Sent { attempts },
    }
}
