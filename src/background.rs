//! A small tokio runtime of a component's own, for blocking callers: the
//! job store on PostgreSQL and the shared files call async clients from
//! worker threads and from the server's handlers alike. A caller hands it
//! a future and waits for the answer; it never enters the caller's runtime
//! (which would panic inside the server) and is shut down in the
//! background when dropped (a component may be dropped inside the server).

use std::future::Future;

pub struct Background {
    rt: Option<tokio::runtime::Runtime>,
}

impl Background {
    /// A runtime of two threads named `name`.
    pub fn new(name: &str) -> std::io::Result<Background> {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name(name)
            .enable_all()
            .build()?;
        Ok(Background { rt: Some(rt) })
    }

    /// Runs `f` and waits for its answer; `None` if the runtime stopped
    /// first.
    pub fn run<T: Send + 'static>(&self, f: impl Future<Output = T> + Send + 'static) -> Option<T> {
        let (tx, rx) = std::sync::mpsc::sync_channel(1);
        self.spawn(async move {
            let _ = tx.send(f.await);
        });
        rx.recv().ok()
    }

    /// Starts `f` and lets it run.
    pub fn spawn(&self, f: impl Future<Output = ()> + Send + 'static) {
        self.rt.as_ref().expect("runtime until drop").spawn(f);
    }
}

impl Drop for Background {
    fn drop(&mut self) {
        if let Some(rt) = self.rt.take() {
            rt.shutdown_background();
        }
    }
}
