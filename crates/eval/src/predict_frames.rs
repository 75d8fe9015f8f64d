//! `predict` over a list of raw frames (sample tokens of a dataroot, issue 44), pipelined:
//! loader threads build each frame's input from the raw files (the JPEG decoded, the radar
//! sweeps rasterised, as `prepare` computes them) while the calling thread runs the network on
//! the frame before, and a writer thread encodes and writes the pictures of the frame before
//! that. The network stays on the calling thread (libtorch's own threads do its work).
//!
//! The depth of a frame is the one `predict` gives for it alone: the same input, the same
//! network call (a test checks it bit for bit).

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::time::Instant;

use depthsense_infer::run::RunStats;
use depthsense_infer::NetError;
use depthsense_nuscenes::depth_png::DepthMap;
use depthsense_progress::Progress;

use crate::predict::PredictInput;

/// Frames loaded ahead of the network, per loader thread.
const AHEAD_PER_LOADER: usize = 2;

/// The three stages of [`predict_frames`]: what each does with frame `i` of `n`.
pub struct Stages<L, N, W> {
    /// Frames in the list.
    pub n: usize,
    /// Loader threads (at least 1).
    pub loaders: usize,
    /// Builds frame `i`'s input (on a loader thread).
    pub load: L,
    /// Runs the network on an input (on the calling thread): its depth.
    pub network: N,
    /// Writes a frame's outputs (on the writer thread).
    pub write: W,
}

/// Runs the pipeline over every frame in `stages`, the frames in the order they finish
/// loading; stops at the first error (the loaders stop taking frames, the writer finishes the
/// frame it holds) and returns it. `progress` counts written frames. The statistics: frames,
/// wall time and each frame's time in the network.
pub fn predict_frames<L, N, W>(
    stages: Stages<L, N, W>,
    progress: &Progress,
) -> Result<RunStats, NetError>
where
    L: Fn(usize) -> Result<PredictInput, NetError> + Sync,
    N: FnMut(&mut PredictInput) -> Result<DepthMap, NetError>,
    W: Fn(&PredictInput, &DepthMap) -> Result<(), NetError> + Sync,
{
    let Stages {
        n,
        loaders,
        load,
        mut network,
        write,
    } = stages;
    let loaders = loaders.clamp(1, n.max(1));
    let started = Instant::now();
    let next = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    progress.set_length(n as u64);
    std::thread::scope(|s| {
        let (in_tx, in_rx) =
            sync_channel::<Result<PredictInput, NetError>>(loaders * AHEAD_PER_LOADER);
        for _ in 0..loaders {
            let tx = in_tx.clone();
            let (load, next, stop) = (&load, &next, &stop);
            s.spawn(move || load_frames(n, load, next, stop, &tx));
        }
        drop(in_tx);
        let (out_tx, out_rx) = sync_channel::<(PredictInput, DepthMap)>(2);
        let (write, stop_w) = (&write, &stop);
        let writer = s.spawn(move || write_frames(write, out_rx, stop_w, progress));
        // Until the loaders are done or one failed (its error arrives in order, after the
        // frames loaded before it), or the writer failed.
        let ran = run_network(&mut network, in_rx, out_tx);
        stop.store(true, Ordering::Relaxed);
        let written = writer
            .join()
            .unwrap_or_else(|_| Err(NetError::ThreadPanicked { thread: "writer" }));
        let batch_ms = ran?;
        written?;
        Ok(RunStats {
            images: batch_ms.len(),
            wall_s: started.elapsed().as_secs_f64(),
            batch_ms,
        })
    })
}

/// A loader thread: takes the next frame index until none is left or the run stops.
fn load_frames<L>(
    n: usize,
    load: &L,
    next: &AtomicUsize,
    stop: &AtomicBool,
    tx: &SyncSender<Result<PredictInput, NetError>>,
) where
    L: Fn(usize) -> Result<PredictInput, NetError>,
{
    while !stop.load(Ordering::Relaxed) {
        let i = next.fetch_add(1, Ordering::Relaxed);
        if i >= n {
            return;
        }
        let failed = {
            let r = load(i);
            let failed = r.is_err();
            if tx.send(r).is_err() {
                return;
            }
            failed
        };
        if failed {
            stop.store(true, Ordering::Relaxed);
            return;
        }
    }
}

/// The calling thread: the network on each loaded frame, handed to the writer; each frame's
/// milliseconds in the network.
fn run_network<N>(
    network: &mut N,
    rx: Receiver<Result<PredictInput, NetError>>,
    tx: SyncSender<(PredictInput, DepthMap)>,
) -> Result<Vec<f64>, NetError>
where
    N: FnMut(&mut PredictInput) -> Result<DepthMap, NetError>,
{
    let mut ms = vec![];
    for loaded in rx {
        let mut input = loaded?;
        let t = Instant::now();
        let depth = network(&mut input)?;
        ms.push(t.elapsed().as_secs_f64() * 1e3);
        if tx.send((input, depth)).is_err() {
            // The writer failed: its error is the run's.
            break;
        }
    }
    Ok(ms)
}

/// The writer thread: each frame's outputs; the first error stops the run.
fn write_frames<W>(
    write: &W,
    rx: Receiver<(PredictInput, DepthMap)>,
    stop: &AtomicBool,
    progress: &Progress,
) -> Result<(), NetError>
where
    W: Fn(&PredictInput, &DepthMap) -> Result<(), NetError>,
{
    for (input, depth) in rx {
        if let Err(e) = write(&input, &depth) {
            stop.store(true, Ordering::Relaxed);
            return Err(e);
        }
        progress.inc(1);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;
    use std::sync::Mutex;

    fn input(i: usize) -> PredictInput {
        let blank = DepthMap {
            width: 2,
            height: 1,
            depth_m: vec![0.0; 2],
        };
        PredictInput {
            name: format!("f{i}"),
            image: image::RgbImage::new(2, 1),
            radar_raw: blank.clone(),
            radar_height: blank,
            gt: None,
            mer: None,
            radar_settings: None,
        }
    }

    fn depth(i: &PredictInput) -> DepthMap {
        let k: f32 = i.name[1..].parse().unwrap();
        DepthMap {
            width: 2,
            height: 1,
            depth_m: vec![k; 2],
        }
    }

    #[test]
    fn every_frame_is_loaded_run_and_written_once() {
        let written = Mutex::new(vec![]);
        let stats = predict_frames(
            Stages {
                n: 23,
                loaders: 3,
                load: |i| Ok(input(i)),
                network: |i: &mut PredictInput| Ok(depth(i)),
                write: |i: &PredictInput, d: &DepthMap| {
                    assert_eq!(d.depth_m[0], i.name[1..].parse::<f32>().unwrap());
                    written.lock().unwrap().push(i.name.clone());
                    Ok(())
                },
            },
            &Progress::hidden(),
        )
        .unwrap();
        let mut w = written.into_inner().unwrap();
        w.sort();
        let mut want: Vec<String> = (0..23).map(|i| format!("f{i}")).collect();
        want.sort();
        assert_eq!(w, want);
        assert_eq!((stats.images, stats.batch_ms.len()), (23, 23));
    }

    #[test]
    fn the_first_error_of_any_stage_is_the_runs() {
        let run = |bad_load: usize, bad_write: usize| {
            predict_frames(
                Stages {
                    n: 40,
                    loaders: 2,
                    load: |i| match i == bad_load {
                        true => Err(NetError::io(
                            Path::new(&format!("f{i}")),
                            std::io::Error::other("cannot load"),
                        )),
                        false => Ok(input(i)),
                    },
                    network: |i: &mut PredictInput| Ok(depth(i)),
                    write: |i: &PredictInput, _: &DepthMap| match i.name == format!("f{bad_write}")
                    {
                        true => Err(NetError::io(
                            Path::new(&i.name),
                            std::io::Error::other("cannot write"),
                        )),
                        false => Ok(()),
                    },
                },
                &Progress::hidden(),
            )
        };
        let e = run(5, usize::MAX).unwrap_err().to_string();
        assert_eq!(e, "f5: cannot load");
        let e = run(usize::MAX, 7).unwrap_err().to_string();
        assert_eq!(e, "f7: cannot write");
        assert_eq!(run(usize::MAX, usize::MAX).unwrap().images, 40);
    }
}
