//! The RAM budget: each frame's working set is estimated from its header
//! before any pixel is decoded, and a frame starts only when that much of the
//! budget is free. A frame larger than the whole budget is refused with the
//! numbers.

use std::sync::{Condvar, Mutex};

use super::raster::FrameHeader;

pub const MIB: u64 = 1 << 20;

/// Resident memory of the process before any frame: code and data of
/// OpenCV, GDAL and PROJ plus the GDAL block cache we allow
/// ([`GDAL_CACHE_MIB`]). The benchmark measures 149 MiB peak for one
/// worker on 4000x3000 frames whose estimated working set is ~50 MiB, so
/// about 100 MiB is the process itself.
pub const BASE_PROCESS_BYTES: u64 = 104 * MIB;

/// GDAL's raster block cache. Strips are read full width, forward, in whole
/// blocks, so the cache is never re-read from; keep it small.
pub const GDAL_CACHE_MIB: u64 = 32;

/// Working memory of the marker detector per tile pixel: OpenCV's aruco
/// keeps one thresholded copy per adaptive-threshold window size (2 here)
/// plus contours and candidate lists. 12 bytes/pixel makes the estimate
/// cover the measured peak (2 workers on 8000x6000: 228 MiB measured,
/// 244 MiB estimated).
const DETECT_BYTES_PER_TILE_PIXEL: u64 = 12;

/// Bytes the stretch pass of a non-8-bit frame holds (decimated samples of
/// every selected band plus one grey copy).
const STRETCH_BYTES_PER_BAND: u64 = 4 * (1 << 20);

/// Working set of one frame: the full-width strip, the chunk read buffer,
/// the detector's per-tile buffers, for wide samples the stretch pass, and
/// what the decoder holds for the file's layout (a progressive JPEG's
/// coefficients, a compressed TIFF's whole strip).
pub fn estimate_frame_bytes(header: &FrameHeader, tile_size: usize) -> u64 {
    let tile_h = tile_size.min(header.height) as u64;
    let tile_w = tile_size.min(header.width) as u64;
    let strip = header.width as u64 * tile_h;
    let chunk = header.chunk_bytes() as u64;
    let detect = DETECT_BYTES_PER_TILE_PIXEL * tile_w * tile_h;
    let stretch = if header.sample_bytes > 1 {
        STRETCH_BYTES_PER_BAND * (header.bands.len() as u64 + 1)
    } else {
        0
    };
    strip + chunk + detect + stretch + header.decoder_bytes
}

/// The budget could not take a frame at all.
#[derive(Debug, Clone, Copy, thiserror::Error)]
#[error("frame needs about {need_mib} MiB but the RAM budget for frames is {budget_mib} MiB (raise --max-ram-gb or lower --tile-size)")]
pub struct TooLarge {
    pub need_mib: u64,
    pub budget_mib: u64,
}

/// A counting semaphore of bytes.
pub struct RamBudget {
    capacity: u64,
    free: Mutex<u64>,
    freed: Condvar,
}

/// Bytes held from a [`RamBudget`]; returned when dropped.
pub struct Permit<'a> {
    budget: &'a RamBudget,
    bytes: u64,
}

impl RamBudget {
    /// Budget for frames under a process limit of `max_ram_bytes`: what is
    /// left after the process's own base footprint.
    pub fn for_process_limit(max_ram_bytes: u64) -> RamBudget {
        RamBudget::new(max_ram_bytes.saturating_sub(BASE_PROCESS_BYTES))
    }

    pub fn new(capacity: u64) -> RamBudget {
        RamBudget {
            capacity,
            free: Mutex::new(capacity),
            freed: Condvar::new(),
        }
    }

    pub fn capacity(&self) -> u64 {
        self.capacity
    }

    /// Bytes currently held by running frames.
    pub fn in_use(&self) -> u64 {
        self.capacity - *self.free.lock().expect("budget lock")
    }

    /// Waits until `bytes` are free and takes them; refuses at once what can
    /// never fit.
    pub fn acquire(&self, bytes: u64) -> Result<Permit<'_>, TooLarge> {
        if bytes > self.capacity {
            return Err(TooLarge {
                need_mib: bytes.div_ceil(MIB),
                budget_mib: self.capacity / MIB,
            });
        }
        let mut free = self.free.lock().expect("budget lock");
        while *free < bytes {
            free = self.freed.wait(free).expect("budget lock");
        }
        *free -= bytes;
        Ok(Permit {
            budget: self,
            bytes,
        })
    }

    /// As [`RamBudget::acquire`], waiting at most `wait`: `Ok(None)` if the
    /// memory did not come free meanwhile (a caller that must do something
    /// else while it waits, such as renewing a lease, calls again).
    pub fn acquire_within(
        &self,
        bytes: u64,
        wait: std::time::Duration,
    ) -> Result<Option<Permit<'_>>, TooLarge> {
        if bytes > self.capacity {
            return Err(TooLarge {
                need_mib: bytes.div_ceil(MIB),
                budget_mib: self.capacity / MIB,
            });
        }
        let free = self.free.lock().expect("budget lock");
        let (mut free, _) = self
            .freed
            .wait_timeout_while(free, wait, |free| *free < bytes)
            .expect("budget lock");
        if *free < bytes {
            return Ok(None);
        }
        *free -= bytes;
        Ok(Some(Permit {
            budget: self,
            bytes,
        }))
    }
}

impl Drop for Permit<'_> {
    fn drop(&mut self) {
        *self.budget.free.lock().expect("budget lock") += self.bytes;
        self.budget.freed.notify_all();
    }
}

/// Memory this process may use by default: half of the machine's memory or
/// of the container's cgroup limit, whichever is smaller.
pub fn default_max_ram_bytes() -> u64 {
    let machine = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("MemTotal:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        })
        .map(|kib| kib * 1024)
        .unwrap_or(4 << 30);
    let cgroup = std::fs::read_to_string("/sys/fs/cgroup/memory.max")
        .ok()
        .and_then(|s| s.trim().parse::<u64>().ok());
    machine.min(cgroup.unwrap_or(u64::MAX)) / 2
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_what_never_fits_and_returns_permits() {
        let b = RamBudget::new(100 * MIB);
        let e = b.acquire(150 * MIB).err().expect("too large");
        assert_eq!((e.need_mib, e.budget_mib), (150, 100));
        {
            let _p = b.acquire(60 * MIB).unwrap();
            assert_eq!(b.in_use(), 60 * MIB);
        }
        assert_eq!(b.in_use(), 0);
    }
}
