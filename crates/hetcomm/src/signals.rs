//! Signals taken as events: SIGINT and SIGTERM (a stop) and SIGHUP (reload the fleet file,
//! [`describe_reload`](crate::describe_reload)), blocked in every thread and waited for by one
//! thread of their own. `hetcomm listen`, `hetcomm record` and the fleet node examples use it.

use std::io;

/// SIGINT and SIGTERM (and SIGHUP, or SIGHUP alone), blocked in every thread and taken by
/// one thread that waits for them (sigwait): no handler runs inside another thread's system
/// call, and the program learns of the signal as an event like a message.
pub struct StopSignals {
    set: libc::sigset_t,
}

impl StopSignals {
    /// Blocks SIGINT and SIGTERM in the calling thread. Call it before any thread starts:
    /// threads inherit the mask, and a thread that does not block them would be killed by
    /// them as before.
    pub fn block() -> io::Result<StopSignals> {
        Self::block_these(&[libc::SIGINT, libc::SIGTERM])
    }

    /// [`StopSignals::block`] and SIGHUP too: [`StopSignals::watch`] hands it to `on_stop`
    /// every time (a reload, not a stop).
    pub fn block_with_reload() -> io::Result<StopSignals> {
        Self::block_these(&[libc::SIGINT, libc::SIGTERM, libc::SIGHUP])
    }

    /// SIGHUP alone, for a program that reloads its fleet file on it
    /// ([`describe_reload`](crate::describe_reload)) and keeps the default SIGINT and
    /// SIGTERM (they end it). [`StopSignals::watch`] hands every SIGHUP to its function.
    pub fn block_reload() -> io::Result<StopSignals> {
        Self::block_these(&[libc::SIGHUP])
    }

    fn block_these(signals: &[libc::c_int]) -> io::Result<StopSignals> {
        // SAFETY: sigemptyset/sigaddset write into the set we own; pthread_sigmask reads it
        // and changes only this thread's mask.
        unsafe {
            let mut set: libc::sigset_t = std::mem::zeroed();
            libc::sigemptyset(&mut set);
            for &signal in signals {
                libc::sigaddset(&mut set, signal);
            }
            let rc = libc::pthread_sigmask(libc::SIG_BLOCK, &set, std::ptr::null_mut());
            if rc != 0 {
                return Err(io::Error::from_raw_os_error(rc));
            }
            Ok(StopSignals { set })
        }
    }

    /// Starts the thread that waits for the signals: the first calls `on_stop` with its
    /// number; a second one (the user insisting) ends the process at once, with the shell's
    /// code for death by that signal (128 + its number).
    pub fn watch(self, on_stop: impl Fn(libc::c_int) + Send + 'static) -> io::Result<()> {
        let set = self.set;
        std::thread::Builder::new()
            .name("signals".into())
            .spawn(move || {
                let mut stopping = false;
                loop {
                    let mut signal: libc::c_int = 0;
                    // SAFETY: sigwait reads the set we own and writes the signal number.
                    if unsafe { libc::sigwait(&set, &mut signal) } != 0 {
                        return;
                    }
                    if signal == libc::SIGHUP {
                        on_stop(signal);
                        continue;
                    }
                    if stopping {
                        std::process::exit(128 + signal);
                    }
                    stopping = true;
                    on_stop(signal);
                }
            })?;
        Ok(())
    }
}
