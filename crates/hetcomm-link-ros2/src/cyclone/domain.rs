//! Cyclone DDS domains and participants for `dds = "cyclone"` transports: the domain's
//! configuration from the transport's settings, and one domain per domain id per process,
//! shared by the links that use it.
//!
//! Cyclone DDS runs one instance of a domain id per process: links of one process on the
//! same domain id (a `LocalFleet`, the tests) share it, and their samples to each other are
//! delivered inside the process without the network. The first link creates the domain with
//! its settings; later links must ask for the same discovery settings; the last one to close
//! deletes it.

use parking_lot::Mutex;
use std::collections::BTreeMap;
use std::ffi::{CStr, CString};

use cyclors::*;

use crate::link::Ros2OpenError;
use crate::settings::{Reliability, Ros2Settings};

/// Cyclone DDS's text for return code `rc` (negative).
pub fn retcode(rc: dds_return_t) -> String {
    // SAFETY: dds_strretcode returns a static NUL-terminated string for any code.
    let text = unsafe { CStr::from_ptr(dds_strretcode(rc)) };
    format!("{} ({rc})", text.to_string_lossy())
}

/// An [`Ros2OpenError`] for a failed creation of `what`.
pub fn dds_err(what: impl Into<String>, rc: dds_return_t) -> Ros2OpenError {
    Ros2OpenError::Dds {
        what: what.into(),
        reason: retcode(rc),
    }
}

/// The domain configuration (Cyclone DDS XML) of `settings`: the interface, and with
/// `same_host` unicast discovery of the first 40 participants on 127.0.0.1 (fixed ports per
/// participant index, as rustdds's and Python `cyclonedds`'s loopback discovery use), so
/// that participants of one host find each other without multicast on `lo`. A
/// `CYCLONEDDS_URI` in the environment is read first, and these settings over it.
pub fn config(settings: &Ros2Settings) -> String {
    let mut xml = String::from("<CycloneDDS><Domain id=\"any\"><General>");
    if let Some(ip) = settings.interface {
        xml.push_str(&format!(
            "<Interfaces><NetworkInterface address=\"{ip}\"/></Interfaces>"
        ));
    }
    xml.push_str("</General><Discovery>");
    if settings.same_host {
        xml.push_str(
            "<ParticipantIndex>auto</ParticipantIndex>\
             <MaxAutoParticipantIndex>40</MaxAutoParticipantIndex>\
             <Peers><Peer address=\"127.0.0.1\"/></Peers>",
        );
    }
    xml.push_str("</Discovery></Domain></CycloneDDS>");
    match std::env::var("CYCLONEDDS_URI") {
        Ok(uri) if !uri.trim().is_empty() => format!("{uri},{xml}"),
        _ => xml,
    }
}

/// A domain open in this process: its handle, configuration and users.
struct Open {
    handle: dds_entity_t,
    config: String,
    users: usize,
}

static DOMAINS: Mutex<BTreeMap<u32, Open>> = Mutex::new(BTreeMap::new());

/// A participant on the settings' domain; deleting it (on drop) releases the domain.
pub struct Participant {
    /// The participant's handle.
    pub handle: dds_entity_t,
    domain: u32,
}

impl Participant {
    /// Creates (or joins) the settings' domain and a participant on it.
    pub fn new(settings: &Ros2Settings) -> Result<Participant, Ros2OpenError> {
        let id = u32::from(settings.domain_id);
        let config = config(settings);
        let mut domains = DOMAINS.lock();
        match domains.get_mut(&id) {
            Some(open) if open.config != config => {
                return Err(Ros2OpenError::Dds {
                    what: format!("the participant on domain {id}"),
                    reason: format!(
                        "Cyclone DDS runs one instance of a domain per process, and domain {id} \
                         is already open here with other `interface` / `same_host` settings \
                         (the configuration of the first link: {})",
                        open.config
                    ),
                })
            }
            Some(open) => open.users += 1,
            None => {
                let text = CString::new(config.clone()).map_err(|_| Ros2OpenError::Dds {
                    what: format!("domain {id}"),
                    reason: "CYCLONEDDS_URI holds a NUL byte".into(),
                })?;
                // SAFETY: a valid C string, copied by Cyclone DDS.
                let handle = unsafe { dds_create_domain(id, text.as_ptr()) };
                if handle < 0 {
                    return Err(dds_err(format!("domain {id}"), handle));
                }
                domains.insert(
                    id,
                    Open {
                        handle,
                        config,
                        users: 1,
                    },
                );
            }
        }
        // SAFETY: plain call; null QoS and listener are allowed.
        let handle = unsafe { dds_create_participant(id, std::ptr::null(), std::ptr::null()) };
        drop(domains);
        let participant = Participant { handle, domain: id };
        if handle < 0 {
            // Dropping releases the domain; the handle is not deleted (it is not one).
            return Err(dds_err(format!("the participant on domain {id}"), handle));
        }
        Ok(participant)
    }
}

impl Drop for Participant {
    fn drop(&mut self) {
        if self.handle > 0 {
            // SAFETY: deletes the participant and everything under it (readers, writers,
            // topics); waits for listener calls in progress.
            unsafe { dds_delete(self.handle) };
        }
        let mut domains = DOMAINS.lock();
        if let Some(open) = domains.get_mut(&self.domain) {
            open.users -= 1;
            if open.users == 0 {
                // SAFETY: the last user is gone.
                unsafe { dds_delete(open.handle) };
                domains.remove(&self.domain);
            }
        }
    }
}

/// The QoS of the transport's readers and writers: reliability, volatile durability,
/// KeepLast history of `history_depth`. Deleted on drop.
pub struct Qos(pub *mut dds_qos_t);

impl Qos {
    /// The readers' QoS.
    pub fn reader(settings: &Ros2Settings) -> Qos {
        Self::new(settings, false)
    }

    /// The writers' QoS: as the readers', but a reliable writer keeps **all** unacknowledged
    /// samples (KeepAll): Cyclone DDS then blocks a write (up to 100 ms, then the send fails
    /// as congested) while its unacknowledged bytes are over its high watermark, where a
    /// KeepLast writer would drop the oldest unacknowledged samples without telling anyone.
    /// History is not matched between writers and readers, so peers see no difference.
    ///
    /// With `deliver_on_receive_thread` the writers never block (`max_blocking_time` 0): a
    /// write on Cyclone's receive thread must not wait for acknowledgements only that thread
    /// reads; the link waits itself on other threads (see the module docs of `cyclone`).
    pub fn writer(settings: &Ros2Settings) -> Qos {
        Self::new(settings, settings.reliability == Reliability::Reliable)
    }

    fn new(settings: &Ros2Settings, keep_all: bool) -> Qos {
        let max_blocking_ns = match keep_all && settings.deliver_on_receive_thread {
            true => 0,
            false => 100_000_000,
        };
        // SAFETY: plain QoS calls on a fresh QoS object.
        unsafe {
            let q = dds_create_qos();
            match settings.reliability {
                Reliability::Reliable => dds_qset_reliability(
                    q,
                    dds_reliability_kind_DDS_RELIABILITY_RELIABLE,
                    max_blocking_ns,
                ),
                Reliability::BestEffort => {
                    dds_qset_reliability(q, dds_reliability_kind_DDS_RELIABILITY_BEST_EFFORT, 0)
                }
            }
            dds_qset_durability(q, dds_durability_kind_DDS_DURABILITY_VOLATILE);
            match keep_all {
                true => dds_qset_history(q, dds_history_kind_DDS_HISTORY_KEEP_ALL, 0),
                false => dds_qset_history(
                    q,
                    dds_history_kind_DDS_HISTORY_KEEP_LAST,
                    settings.history_depth,
                ),
            }
            Qos(q)
        }
    }
}

impl Drop for Qos {
    fn drop(&mut self) {
        // SAFETY: created by dds_create_qos, deleted once.
        unsafe { dds_delete_qos(self.0) };
    }
}

/// A topic of raw samples (`cyclors`'s blob type: the serialized bytes as they are on the
/// wire, with their encapsulation header) named `topic`, of DDS type `type_name`.
pub fn blob_topic(
    participant: dds_entity_t,
    topic: &str,
    type_name: &str,
) -> Result<dds_entity_t, Ros2OpenError> {
    let bad = |_| Ros2OpenError::Dds {
        what: format!("topic {topic}"),
        reason: "the name holds a NUL byte".into(),
    };
    let t = CString::new(topic).map_err(bad)?;
    let ty = CString::new(type_name).map_err(bad)?;
    // SAFETY: both strings are copied (the type name into the sertype, the topic name into
    // the topic); the pointers are only read although the binding takes them as `*mut`.
    let handle = unsafe {
        cdds_create_blob_topic(
            participant,
            t.as_ptr() as *mut _,
            ty.as_ptr() as *mut _,
            true,
        )
    };
    if handle < 0 {
        return Err(dds_err(format!("topic {topic}"), handle));
    }
    Ok(handle)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_configuration_follows_the_settings() {
        let mut s = Ros2Settings::default();
        let c = config(&s);
        assert!(c.contains("<Peer address=\"127.0.0.1\"/>"), "{c}");
        assert!(!c.contains("NetworkInterface"), "{c}");
        s.same_host = false;
        s.interface = Some("10.0.0.2".parse().unwrap());
        let c = config(&s);
        assert!(!c.contains("Peer"), "{c}");
        assert!(
            c.contains("<NetworkInterface address=\"10.0.0.2\"/>"),
            "{c}"
        );
    }
}
