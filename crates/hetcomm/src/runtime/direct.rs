//! In-process hand-over: a frame to a system of this process goes straight to its router,
//! on the sender's thread, without a link.

use super::*;

impl SystemCore {
    /// Enables direct hand-over on the links that `names` marks as in-process (see
    /// [`DirectRoutes`]).
    pub(crate) fn set_direct(&self, hubs: Hubs, names: Vec<Option<String>>) {
        if names.iter().any(Option::is_some) {
            let _ = self.direct.set(DirectRoutes {
                hubs,
                names,
                cache: Mutex::new(HashMap::default()),
            });
        }
    }

    /// The destination system when a send to `to` over `link` can be handed over directly.
    pub(crate) fn direct_peer(&self, link: usize, to: SystemId) -> Option<Arc<SystemCore>> {
        if !self.may_skip_links() {
            return None;
        }
        let d = self.direct.get()?;
        let name = d.names.get(link)?.as_ref()?;
        let mut cache = d.cache.lock();
        if let Some(c) = cache.get(&to).and_then(Weak::upgrade) {
            if !c.is_closed() {
                return Some(c);
            }
        }
        let c = d.hubs.system(name, to)?;
        cache.insert(to, Arc::downgrade(&c));
        Some(c)
    }

    /// Takes the next message `accept` agrees to from `module`'s inbox, waiting up to
    /// `timeout` (None: forever). While it waits, the thread reads the links itself when it
    /// can (see [`crate::reactor`]). `Err(header)`: the next message was refused and stays.
    pub(crate) fn take_waiting(
        &self,
        module: &ModuleCore,
        accept: impl Fn(&Header) -> bool,
        timeout: Option<Duration>,
    ) -> Result<Option<Entry>, Header> {
        // Whatever this system held back for batching goes out before its thread waits
        // (typically for the answer to it).
        self.flush_held(None);
        let Some(reactor) = self.reactor.get() else {
            return module.inbox.take_timeout(accept, timeout);
        };
        // The deadline is computed only once the inbox turned out empty: a receiver keeping up
        // with a stream finds a message at once nearly every time, and reading the clock
        // is a noticeable part of taking a small message.
        let mut deadline: Option<Option<Instant>> = None;
        loop {
            match module.inbox.try_take(&accept) {
                Ok(None) => {}
                other => return other,
            }
            // (Links that batch are links with a readable side, so they have a reactor.)
            self.idle_before_blocking();
            let deadline = *deadline.get_or_insert_with(|| timeout.map(|t| Instant::now() + t));
            let left = match deadline {
                None => Duration::MAX,
                Some(d) => {
                    let left = d.saturating_duration_since(Instant::now());
                    if left.is_zero() {
                        return Ok(None);
                    }
                    left
                }
            };
            if self.is_closed() {
                return Ok(None);
            }
            if reactor.try_lead() {
                module.leading.store(true, Ordering::SeqCst);
                // A message may have arrived between `try_take` and raising the flag.
                if module.inbox.is_empty() && !spin_on_links(reactor, module, left) {
                    reactor.turn(left);
                }
                module.leading.store(false, Ordering::SeqCst);
                reactor.end_module_turn();
            } else {
                // Someone else reads; it queues what comes. Ask again soon: the leader may
                // be the background thread stepping aside for us.
                reactor.follow(true);
                let r = module
                    .inbox
                    .take_timeout(&accept, Some(left.min(Duration::from_micros(500))));
                reactor.follow(false);
                match r {
                    Ok(None) => {}
                    other => return other,
                }
            }
        }
    }

    /// Puts a message handed over directly by another system of this process into its
    /// module's inbox, through this system's way in ([`SystemCore::arrive`]). `now` is the
    /// sender's clock reading: one process, one clock. `module`: this system's module the
    /// message is for, looked up by the caller (None: there is no such module).
    pub(crate) fn deliver_direct(
        &self,
        module: Option<&ModuleCore>,
        header: Header,
        payload: PayloadBuf,
        now: Time,
    ) -> AckStatus {
        self.direct_received.fetch_add(1, Ordering::Relaxed);
        self.arrive(module, header, payload, now, Source::SameProcess)
    }

    /// [`SystemCore::deliver_direct`] for a batch of messages to one module, in order:
    /// `status` gets each one's answer. The batch goes into the inbox through its lock once
    /// when nothing watches or diverts these messages (observers, taps, callbacks); otherwise
    /// each takes the one-message path.
    pub(crate) fn deliver_direct_many(
        &self,
        module: Option<&ModuleCore>,
        messages: impl ExactSizeIterator<Item = (Header, PayloadBuf)>,
        now: Time,
        mut status: impl FnMut(AckStatus),
    ) {
        let Some(m) = module.filter(|m| self.arrivals_plain(m)) else {
            for (header, payload) in messages {
                status(self.deliver_direct(module, header, payload, now));
            }
            return;
        };
        self.direct_received
            .fetch_add(messages.len() as u64, Ordering::Relaxed);
        let received_at = self.clock.wall(now);
        let entries = messages.map(|(header, payload)| Entry {
            header,
            payload,
            received_at,
        });
        m.inbox.push_many(entries, |pushed| {
            status(match pushed {
                Ok(()) => AckStatus::Delivered,
                Err(PushError::Full) | Err(PushError::Closed) => AckStatus::InboxFull,
            })
        });
        if m.leading.load(Ordering::SeqCst) && !leading_here() {
            if let Some(r) = self.reactor.get() {
                r.kick();
            }
        }
    }
}
