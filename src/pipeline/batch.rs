//! Many frames on a bounded set of worker threads under one RAM budget.
//! Results come back in input order, so output bytes do not depend on the
//! number of threads or on which frame finished first.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use super::frame::{
    detect_frame, detect_frame_pictured, need_bytes, FrameError, FrameObserver, FrameOptions,
    FrameResult, NoObserver,
};
use super::georef::Transformer;
use super::memory::RamBudget;
use super::raster::open_frame;

/// A frame to process: where it is and what to call it in outputs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameInput {
    pub path: PathBuf,
    pub name: String,
}

/// One frame's outcome.
pub type FrameOutcome = Result<FrameResult, FrameError>;

/// Settings for a batch.
#[derive(Debug, Clone)]
pub struct BatchOptions {
    pub frame: FrameOptions,
    pub threads: usize,
    /// The process's memory limit; frames share what is left after the
    /// process's base footprint.
    pub max_ram_bytes: u64,
    /// A folder for each target's chip and each frame's preview (see
    /// [`super::pictures`]); none makes no pictures.
    pub chips: Option<PathBuf>,
}

/// Processes `inputs` and returns one outcome per input, in input order.
/// `on_frame` is called as each frame ends (from worker threads).
pub fn run_batch(
    inputs: &[FrameInput],
    options: &BatchOptions,
    on_frame: &(dyn Fn(&FrameInput, &FrameOutcome) + Sync),
) -> Vec<FrameOutcome> {
    super::init_native();
    let budget = RamBudget::for_process_limit(options.max_ram_bytes);
    let next = AtomicUsize::new(0);
    let slots: Vec<Mutex<Option<FrameOutcome>>> = inputs.iter().map(|_| Mutex::new(None)).collect();
    let workers = options.threads.clamp(1, inputs.len().max(1));
    std::thread::scope(|scope| {
        for worker in 0..workers {
            let (budget, next, slots) = (&budget, &next, &slots);
            std::thread::Builder::new()
                .name(format!("frame-worker-{worker}"))
                .spawn_scoped(scope, move || {
                    // PROJ objects are per thread; reuse them across frames.
                    let mut transformer = Transformer::default();
                    loop {
                        let i = next.fetch_add(1, Ordering::SeqCst);
                        let Some(input) = inputs.get(i) else { break };
                        let outcome = run_one(
                            input,
                            &options.frame,
                            budget,
                            &mut transformer,
                            &NoObserver,
                            options.chips.as_deref(),
                        );
                        on_frame(input, &outcome);
                        *slots[i].lock().expect("slot lock") = Some(outcome);
                    }
                })
                .expect("spawn frame worker");
        }
    });
    slots
        .into_iter()
        .map(|s| s.into_inner().expect("slot lock").expect("every frame ran"))
        .collect()
}

/// Opens one frame, waits for its share of the budget, and runs it; with
/// `chips`, writes the frame's chips and preview into that folder as
/// `NAME.N.png` (N: the target's place in the frame's results, from 0) and
/// `NAME.preview.jpg`, NAME being the frame's name with `/` as `_`.
pub fn run_one(
    input: &FrameInput,
    options: &FrameOptions,
    budget: &RamBudget,
    transformer: &mut Transformer,
    observer: &dyn FrameObserver,
    chips: Option<&Path>,
) -> FrameOutcome {
    let span = tracing::info_span!("frame", image = %input.name);
    let _enter = span.enter();
    let frame = open_frame(&input.path)?;
    let need = need_bytes(frame.header(), options, chips.is_some());
    let _permit = budget.acquire(need)?;
    tracing::debug!(need_mib = need >> 20, "frame admitted");
    let Some(dir) = chips else {
        return detect_frame(frame, &input.name, options, transformer, observer);
    };
    let (result, pictures) =
        detect_frame_pictured(frame, &input.name, options, transformer, observer)?;
    let stem = input.name.replace(['/', '\\'], "_");
    let write = |name: String, bytes: &[u8]| {
        std::fs::write(dir.join(&name), bytes).map_err(|e| {
            FrameError::Picture(format!("cannot write {}: {e}", dir.join(name).display()))
        })
    };
    for (i, chip) in pictures.chips.iter().enumerate() {
        write(format!("{stem}.{i}.png"), chip)?;
    }
    write(format!("{stem}.preview.jpg"), &pictures.preview)?;
    Ok(result)
}
