//! Gloo over loopback with real processes: this test binary re-runs itself as the workers
//! (`DSD_TEST_MODE` set), so every rank is its own process as under torchrun.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use depthsense_dist::sync_bn::{batch_norm, BnState};
use depthsense_dist::{
    broadcast_flat, Backend, DistEnv, GradBuckets, ProcessGroup, ReduceOp, StoreHost,
};
use tch::{Device, Kind, Tensor};

fn free_port() -> u16 {
    depthsense_dist::launch::free_port().expect("a free port")
}

struct Out {
    code: Option<i32>,
    stderr: String,
    seconds: f64,
}

/// Run `world` workers of `mode` (only `ranks` of them started) and collect their results.
fn launch(mode: &str, world: usize, ranks: &[usize], timeout_s: u64) -> Vec<Out> {
    launch_on(free_port(), &[], mode, world, ranks, timeout_s)
}

fn launch_on(
    port: u16,
    extra_env: &[(&str, &str)],
    mode: &str,
    world: usize,
    ranks: &[usize],
    timeout_s: u64,
) -> Vec<Out> {
    let exe = std::env::current_exe().unwrap();
    let children: Vec<_> = ranks
        .iter()
        .map(|&r| {
            let c = Command::new(&exe)
                .args(["--exact", "worker", "--nocapture", "--test-threads=1"])
                .env("DSD_TEST_MODE", mode)
                .env("DSD_TEST_TIMEOUT", timeout_s.to_string())
                .env("RANK", r.to_string())
                .env("LOCAL_RANK", r.to_string())
                .env("WORLD_SIZE", world.to_string())
                .env("MASTER_ADDR", "127.0.0.1")
                .env("MASTER_PORT", port.to_string())
                .envs(extra_env.iter().copied())
                .stdout(Stdio::null())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap();
            (Instant::now(), c)
        })
        .collect();
    children
        .into_iter()
        .map(|(t0, c)| {
            let o = c.wait_with_output().unwrap();
            Out {
                code: o.status.code(),
                stderr: String::from_utf8_lossy(&o.stderr).into_owned(),
                seconds: t0.elapsed().as_secs_f64(),
            }
        })
        .collect()
}

fn group() -> ProcessGroup {
    let timeout: u64 = std::env::var("DSD_TEST_TIMEOUT").unwrap().parse().unwrap();
    let env = DistEnv::from_env().unwrap().unwrap();
    match ProcessGroup::new(&env, Backend::Gloo, None, Duration::from_secs(timeout)) {
        Ok(pg) => pg,
        Err(e) => {
            eprintln!("WORKER-ERROR: {e}");
            std::process::exit(3);
        }
    }
}

fn close(a: &Tensor, b: &Tensor, tol: f64) -> bool {
    let d = (a - b).abs().max().double_value(&[]);
    let s = b.abs().max().double_value(&[]).max(1e-12);
    d / s < tol
}

fn collectives(pg: &ProcessGroup) {
    let (r, n) = (pg.rank() as f64, pg.world_size() as f64);
    // all-reduce sum / average of two tensors at once
    let a = Tensor::full([3], r + 1.0, (Kind::Float, Device::Cpu));
    let b = Tensor::full([2, 2], 2.0 * r, (Kind::Double, Device::Cpu));
    pg.all_reduce(&[a.shallow_clone(), b.shallow_clone()], ReduceOp::Sum)
        .unwrap();
    assert_eq!(a.double_value(&[0]), n * (n + 1.0) / 2.0);
    assert_eq!(b.double_value(&[1, 1]), n * (n - 1.0));
    let c = Tensor::full([4], r, (Kind::Float, Device::Cpu));
    pg.all_reduce(std::slice::from_ref(&c), ReduceOp::Avg)
        .unwrap();
    assert!((c.double_value(&[2]) - (n - 1.0) / 2.0).abs() < 1e-6);
    // broadcast from the last rank, flat-bucketed
    let ts = vec![
        Tensor::full([5], r, (Kind::Float, Device::Cpu)),
        Tensor::full([2, 3], 10.0 + r, (Kind::Float, Device::Cpu)),
        Tensor::full([1], r as i64, (Kind::Int64, Device::Cpu)),
    ];
    broadcast_flat(pg, &ts, pg.world_size() - 1, 16).unwrap();
    assert_eq!(ts[0].double_value(&[4]), n - 1.0);
    assert_eq!(ts[1].double_value(&[1, 2]), 10.0 + n - 1.0);
    assert_eq!(ts[2].int64_value(&[0]), (n - 1.0) as i64);
    pg.barrier().unwrap();
    // autograd all-reduce: y = Σ_ranks x_r·(r+1); L_r = Σ y·(r+1)  →  ∂(Σ_r L_r)/∂x_r
    // = (r+1)·Σ_r'(r'+1); the rank's backward yields exactly that.
    let x = Tensor::ones([3], (Kind::Float, Device::Cpu)).set_requires_grad(true);
    let y = pg.all_reduce_sum_autograd(&(&x * (r + 1.0))).unwrap();
    assert!((y.double_value(&[0]) - n * (n + 1.0) / 2.0).abs() < 1e-6);
    (y * (r + 1.0)).sum(Kind::Float).f_backward().unwrap();
    let expect = (r + 1.0) * n * (n + 1.0) / 2.0;
    assert!((x.grad().double_value(&[1]) - expect).abs() < 1e-5);
    // gradient buckets: average of differing gradients, several buckets
    let p1 = Tensor::zeros([10], (Kind::Float, Device::Cpu)).set_requires_grad(true);
    let p2 = Tensor::zeros([3, 4], (Kind::Float, Device::Cpu)).set_requires_grad(true);
    ((&p1 * (r + 1.0)).sum(Kind::Float) + (&p2 * (2.0 * r)).sum(Kind::Float)).backward();
    let gb = GradBuckets::new(vec![p1.shallow_clone(), p2.shallow_clone()], 48);
    assert_eq!(gb.bucket_bytes().len(), 2);
    let st = gb.all_reduce(pg).unwrap();
    assert_eq!(st.buckets, 2);
    assert!((p1.grad().double_value(&[3]) - (n + 1.0) / 2.0).abs() < 1e-6);
    assert!((p2.grad().double_value(&[2, 3]) - (n - 1.0)).abs() < 1e-6);
}

/// SyncBN on N ranks × B equals native batch norm on the N·B batch: output, running stats,
/// and the gradients of input (this rank's slice), weight and bias (summed over ranks).
fn sync_bn(pg: &ProcessGroup) {
    let (r, n) = (pg.rank() as i64, pg.world_size() as i64);
    let (b, c, h, w) = (2i64, 3i64, 4i64, 5i64);
    let total = n * b * c * h * w;
    let vals: Vec<f32> = (0..total)
        .map(|i| ((i * 7919 % 1013) as f32 / 1013.0) * 4.0 - 1.5 + (i % 3) as f32)
        .collect();
    let full = Tensor::from_slice(&vals).view([n * b, c, h, w]);
    let coef: Vec<f32> = (0..total)
        .map(|i| ((i * 31 % 17) as f32) / 17.0 - 0.4)
        .collect();
    let coef = Tensor::from_slice(&coef).view([n * b, c, h, w]);
    let weight0 = Tensor::from_slice(&[1.0f32, 0.5, 2.0]);
    let bias0 = Tensor::from_slice(&[0.1f32, -0.2, 0.3]);
    // reference: native on the full batch
    let xr = full.copy().set_requires_grad(true);
    let wr = weight0.copy().set_requires_grad(true);
    let br = bias0.copy().set_requires_grad(true);
    let rm_r = Tensor::zeros([c], (Kind::Float, Device::Cpu));
    let rv_r = Tensor::ones([c], (Kind::Float, Device::Cpu));
    let yr = Tensor::batch_norm(
        &xr,
        Some(&wr),
        Some(&br),
        Some(&rm_r),
        Some(&rv_r),
        true,
        0.1,
        1e-5,
        false,
    );
    ((&yr * &coef).sum(Kind::Float) / n as f64).backward();
    // this rank
    let xs = full.narrow(0, r * b, b).copy().set_requires_grad(true);
    let ws = weight0.copy().set_requires_grad(true);
    let bs = bias0.copy().set_requires_grad(true);
    let rm = Tensor::zeros([c], (Kind::Float, Device::Cpu));
    let rv = Tensor::ones([c], (Kind::Float, Device::Cpu));
    let ys = batch_norm(
        pg,
        &xs,
        &BnState {
            weight: Some(&ws),
            bias: Some(&bs),
            running_mean: &rm,
            running_var: &rv,
            momentum: 0.1,
            eps: 1e-5,
        },
    )
    .unwrap();
    // the mean over ranks of the per-rank losses = the reference loss
    ((&ys * coef.narrow(0, r * b, b)).sum(Kind::Float) / n as f64)
        .f_backward()
        .unwrap();
    assert!(close(&ys, &yr.narrow(0, r * b, b), 1e-5), "output");
    assert!(close(&rm, &rm_r, 1e-5), "running mean");
    assert!(close(&rv, &rv_r, 1e-5), "running var");
    assert!(
        close(&xs.grad(), &xr.grad().narrow(0, r * b, b), 1e-4),
        "dx"
    );
    let gw = ws.grad().copy();
    let gbias = bs.grad().copy();
    pg.all_reduce(&[gw.shallow_clone(), gbias.shallow_clone()], ReduceOp::Sum)
        .unwrap();
    assert!(close(&gw, &wr.grad(), 1e-4), "dweight");
    assert!(close(&gbias, &br.grad(), 1e-4), "dbias");
}

#[test]
fn worker() {
    let Ok(mode) = std::env::var("DSD_TEST_MODE") else {
        return; // the parent run: nothing to do here
    };
    let pg = group();
    match mode.as_str() {
        "collectives" => collectives(&pg),
        "sync_bn" => sync_bn(&pg),
        "kill" => {
            pg.barrier().unwrap();
            if pg.rank() == 1 {
                let pid = std::process::id().to_string();
                let _ = Command::new("kill").args(["-9", &pid]).status();
                std::thread::sleep(Duration::from_secs(60));
            }
            let t = Tensor::ones([1000], (Kind::Float, Device::Cpu));
            let t0 = Instant::now();
            loop {
                if let Err(e) = pg.all_reduce(std::slice::from_ref(&t), ReduceOp::Sum) {
                    eprintln!(
                        "WORKER-ERROR after {:.1} s: {e}",
                        t0.elapsed().as_secs_f64()
                    );
                    std::process::exit(3);
                }
            }
        }
        o => panic!("unknown mode {o}"),
    }
    pg.barrier().unwrap();
}

#[test]
fn collectives_on_three_ranks() {
    for o in launch("collectives", 3, &[0, 1, 2], 60) {
        assert_eq!(o.code, Some(0), "{}", o.stderr);
    }
}

#[test]
fn sync_batch_norm_equals_batch_norm_on_the_global_batch() {
    for o in launch("sync_bn", 2, &[0, 1], 60) {
        assert_eq!(o.code, Some(0), "{}", o.stderr);
    }
}

#[test]
fn a_killed_rank_is_named_by_the_survivors() {
    let timeout = 20;
    let outs = launch("kill", 3, &[0, 1, 2], timeout);
    assert_eq!(outs[1].code, None, "rank 1 was killed by a signal");
    for r in [0, 2] {
        let o = &outs[r];
        assert_eq!(o.code, Some(3), "rank {r}: {}", o.stderr);
        assert!(
            o.stderr.contains("rank 1 has stopped"),
            "rank {r} does not name rank 1: {}",
            o.stderr
        );
        assert!(
            o.seconds < timeout as f64 + 10.0,
            "rank {r}: {} s",
            o.seconds
        );
    }
}

#[test]
fn a_missing_rank_fails_the_rendezvous_naming_it() {
    let t0 = Instant::now();
    let outs = launch("collectives", 2, &[0], 3);
    let o = &outs[0];
    assert_eq!(o.code, Some(3), "{}", o.stderr);
    assert!(
        o.stderr.contains("rank 1 of WORLD_SIZE=2 did not join"),
        "{}",
        o.stderr
    );
    assert!(t0.elapsed().as_secs_f64() < 30.0);
}

#[test]
fn under_torchrun_the_agent_hosts_the_store_and_rank_zero_is_a_client() {
    let port = free_port();
    let _agent = StoreHost::new("127.0.0.1", port, Duration::from_secs(60)).unwrap();
    let env = [
        ("TORCHELASTIC_USE_AGENT_STORE", "True"),
        ("TORCHELASTIC_RESTART_COUNT", "1"),
    ];
    for o in launch_on(port, &env, "collectives", 2, &[0, 1], 60) {
        assert_eq!(o.code, Some(0), "{}", o.stderr);
    }
}
