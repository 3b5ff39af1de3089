//! What every proxy shares: the instance handle that destroys it when dropped, and the health
//! that marks it unusable after a panic or a missed deadline.

use super::*;

/// Health of one plugin instance, shared by its proxy and the host that created it.
#[derive(Debug)]
pub(super) struct Health {
    pub(super) kind: PluginKind,
    pub(super) label: String,
    pub(super) poisoned: AtomicBool,
    pub(super) message: Mutex<Option<String>>,
}

impl Health {
    pub(super) fn new(kind: PluginKind, label: String) -> Arc<Self> {
        Arc::new(Self {
            kind,
            label,
            poisoned: AtomicBool::new(false),
            message: Mutex::new(None),
        })
    }

    pub(super) fn poisoned(&self) -> bool {
        self.poisoned.load(Ordering::Acquire)
    }

    pub(super) fn poison(&self, message: &str) {
        let mut m = self.message.lock().unwrap_or_else(|e| e.into_inner());
        if m.is_none() {
            *m = Some(message.to_owned());
        }
        self.poisoned.store(true, Ordering::Release);
    }

    pub(super) fn message(&self) -> String {
        self.message
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
            .unwrap_or_default()
    }

    /// Marks the instance dead after a missed deadline, logs it and returns the message.
    pub(super) fn timed_out(&self, call: &str, deadline: Duration) -> String {
        let message = format!(
            "{} did not return from `{call}` within its deadline of {}; the instance is marked \
             dead and every later call fails at once",
            self.label,
            deadline::describe(deadline)
        );
        self.poison(&message);
        eprintln!("warning: {message}");
        message
    }

    /// Marks the instance dead after its worker thread ended (a bug in the host's code).
    pub(super) fn worker_gone(&self) -> String {
        let message = format!("{}: its worker thread ended unexpectedly", self.label);
        self.poison(&message);
        message
    }
}

/// A plugin instance that became unusable.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PluginFailure {
    /// What the instance was.
    pub kind: PluginKind,
    /// `<kind> <name> from <library>`.
    pub instance: String,
    /// The panic, last error or missed deadline that made it unusable.
    pub message: String,
}

/// The instance part shared by the three proxies: it destroys the instance when dropped.
pub(super) struct Handle {
    pub(super) instance: NonNull<c_void>,
    pub(super) destroy: DestroyFn,
    pub(super) last_error: Option<LastErrorFn>,
    pub(super) health: Arc<Health>,
    pub(super) library: Arc<PluginLibrary>,
}

// SAFETY: the ABI requires constraint and embodiment instances to accept concurrent calls from
// any thread; a planner's handle is only used through `&mut` (or by its one worker thread), so
// never concurrently.
unsafe impl Send for Handle {}
// SAFETY: as above.
unsafe impl Sync for Handle {}

impl Handle {
    pub(super) fn ptr(&self) -> *mut c_void {
        self.instance.as_ptr()
    }

    /// The instance's last error message (empty without a `last_error` slot).
    pub(super) fn last_error(&self) -> String {
        let Some(last_error) = self.last_error else {
            return String::new();
        };
        let mut buf = vec![0u8; 512];
        for _ in 0..2 {
            let mut out = H2nBuffer {
                data: buf.as_mut_ptr(),
                capacity: buf.len(),
                len: 0,
            };
            // SAFETY: live instance; host-owned buffer of the stated capacity.
            unsafe { last_error(self.ptr(), &mut out) };
            if out.len <= buf.len() {
                return buffer_text(&buf, out.len);
            }
            buf.resize(out.len.min(MAX_MESSAGE_BYTES), 0);
        }
        buffer_text(&buf, buf.len())
    }

    /// Turns a non-OK status into a message, poisoning the instance on a panic.
    pub(super) fn failure(&self, status: H2nStatus) -> String {
        let message = self.last_error();
        let message = if message.is_empty() {
            status_name(status).to_owned()
        } else {
            message
        };
        if status == H2N_PANIC || status == H2N_POISONED {
            self.health.poison(&message);
        }
        message
    }
}

impl Drop for Handle {
    fn drop(&mut self) {
        // SAFETY: the instance is live, no call on it is in progress (the handle is dropped
        // by its only user), and this is the only place it is destroyed.
        unsafe { (self.destroy)(self.ptr()) };
    }
}

impl fmt::Debug for Handle {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Handle")
            .field("health", &self.health)
            .finish()
    }
}
