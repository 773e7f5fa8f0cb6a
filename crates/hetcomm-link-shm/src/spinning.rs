//! The receiver's "I am spinning" flag, through which senders skip the wake-up system call.
//!
//! Each system publishes, on an iceoryx2 blackboard service of its own service's name (the
//! blackboard pattern keeps it apart from the publish-subscribe and event services of that
//! name), one `u32` entry: 1 while a thread spins on its queue, 0 otherwise. Senders read it
//! after each sample and notify the receiver's listener only when it is 0.
//!
//! No wake-up is lost (a Dekker handshake): a sender puts its sample in the queue, fences
//! (`SeqCst`), then reads the flag; a receiver that stops spinning clears the flag, fences,
//! then looks at its queue once more and wakes its own descriptor if a sample is there. Of
//! the two fences one comes first: either the sender sees the flag cleared and notifies, or
//! the receiver sees the sample. A receiver without the flag (a foreign peer, or one whose
//! blackboard could not be opened) is always notified; a receiver that cannot create its flag
//! still spins on its queue, and its senders keep notifying.

use std::sync::atomic::{fence, Ordering};
use std::sync::OnceLock;

use iceoryx2::port::reader::{EntryHandle, Reader};
use iceoryx2::port::writer::{EntryHandleMut, Writer};
use iceoryx2::prelude::*;
use iceoryx2::service::builder::blackboard::BlackboardCreateError;
use iceoryx2::service::port_factory::blackboard::PortFactory;

use crate::IpcService;

/// The flag's only key.
const KEY: u8 = 0;
/// The flag's value while the receiver spins.
const SPINNING: u32 = 1;
/// The flag's value otherwise (also its value when the blackboard is created).
const NOT_SPINNING: u32 = 0;

/// A receiver's own flag: it alone writes it (a blackboard has one writer).
pub(crate) struct OwnFlag {
    entry: EntryHandleMut<IpcService, u8, u32>,
    _writer: Writer<IpcService, u8>,
    _service: PortFactory<IpcService, u8>,
}

impl OwnFlag {
    /// Creates (or, after a restart, reopens) the flag on `service`, admitting `readers`
    /// senders. None when iceoryx2 refuses: the receiver then goes without (always notified).
    pub(crate) fn open(
        node: &Node<IpcService>,
        service: &str,
        readers: usize,
        nodes: usize,
    ) -> Option<OwnFlag> {
        let name = ServiceName::new(service).ok()?;
        let created = node
            .service_builder(&name)
            .blackboard_creator::<u8>()
            .max_readers(readers)
            .max_nodes(nodes)
            .add::<u32>(KEY, NOT_SPINNING)
            .create();
        let factory = match created {
            Ok(f) => f,
            // Senders kept it open across this system's restart: take it over.
            Err(BlackboardCreateError::AlreadyExists) => node
                .service_builder(&name)
                .blackboard_opener::<u8>()
                .open()
                .ok()?,
            Err(_) => return None,
        };
        let writer = factory.writer_builder().create().ok()?;
        let entry = writer.entry::<u32>(&KEY).ok()?;
        // A predecessor that crashed while spinning left 1.
        entry.update_with_copy(NOT_SPINNING);
        Some(OwnFlag {
            entry,
            _writer: writer,
            _service: factory,
        })
    }

    /// Says the receiver spins (senders stop notifying) or stopped. After `false` the caller
    /// must look at its queue (the fence here orders that look after the store).
    pub(crate) fn set(&self, spinning: bool) {
        self.entry
            .update_with_copy(if spinning { SPINNING } else { NOT_SPINNING });
        if !spinning {
            fence(Ordering::SeqCst);
        }
    }
}

/// A sender's view of one destination's flag, opened once the destination has made it.
#[derive(Default)]
pub(crate) struct PeerFlag {
    opened: OnceLock<PeerEntry>,
}

struct PeerEntry {
    entry: EntryHandle<IpcService, u8, u32>,
    _reader: Reader<IpcService, u8>,
    _service: PortFactory<IpcService, u8>,
}

impl PeerFlag {
    /// Opens the destination's flag if it is not open yet and the destination has made it.
    pub(crate) fn try_open(&self, node: &Node<IpcService>, service: &str) {
        if self.opened.get().is_some() {
            return;
        }
        let Ok(name) = ServiceName::new(service) else {
            return;
        };
        let Ok(factory) = node.service_builder(&name).blackboard_opener::<u8>().open() else {
            return;
        };
        let Ok(reader) = factory.reader_builder().create() else {
            return;
        };
        let Ok(entry) = reader.entry::<u32>(&KEY) else {
            return;
        };
        let _ = self.opened.set(PeerEntry {
            entry,
            _reader: reader,
            _service: factory,
        });
    }

    /// Whether the destination needs a notification for a sample just sent: true unless its
    /// flag says it spins. Call after the sample is in its queue (the fence orders the read
    /// after it).
    pub(crate) fn needs_wake(&self) -> bool {
        let Some(p) = self.opened.get() else {
            return true;
        };
        fence(Ordering::SeqCst);
        *p.entry.get() != SPINNING
    }
}
