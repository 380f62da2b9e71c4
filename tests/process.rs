//! Tests that measure what belongs to the whole process: its resident memory. They have a
//! binary of their own, since the suite's (`tests/suite/`) runs many tests at once in one
//! process, and take one lock, so that here too they run one at a time.

#[path = "suite/common/mod.rs"]
mod common;

use std::sync::{Arc, Mutex};

use common::with_gpu;
use vkinverse::gpu::{Buffer, CommandBuffer, Context, MemoryKind};
use vkinverse::ops::BufferOps;
use vkinverse::render::gradient::{GradientInputs, GradientPass};
use vkinverse::render::{GpuScene, PrimalRenderer};
use vkinverse::scene::{Film, LoadOptions, Loss, Scene};

static ALONE: Mutex<()> = Mutex::new(());

fn alone() -> std::sync::MutexGuard<'static, ()> {
    ALONE.lock().unwrap_or_else(|p| p.into_inner())
}

/// Resident pages of this process (the second field of /proc/self/statm).
fn resident_pages() -> u64 {
    let statm = std::fs::read_to_string("/proc/self/statm").unwrap();
    statm.split_whitespace().nth(1).unwrap().parse().unwrap()
}

fn device_memory(ctx: &Context) -> (usize, u64) {
    let live = ctx.live_allocations();
    (live.len(), live.iter().map(|(_, bytes)| bytes).sum())
}

/// Resident-memory growth allowed over 1000 iterations: 64 pages (256 KiB with 4 KiB
/// pages). Measured growth over 6 runs of the same loop on a Cornell box of the same size
/// and depth (before it moved here): 0 to 10 pages. A leak of 262 bytes per iteration or
/// more exceeds it.
const HOST_SLACK_PAGES: u64 = 64;

/// A recorded gradient pass (the bundled Cornell box at 8 × 8, depth 4, 1 spp)
/// resubmitted 1000 times allocates nothing on the device and keeps the host's resident
/// memory flat.
#[test]
fn thousand_resubmitted_gradient_iterations_keep_memory_constant() {
    let _alone = alone();
    let options = LoadOptions { film: Some(Film { width: 8, height: 8 }), max_depth: Some(4) };
    let scene = Scene::load_with(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/cornell/scene.toml"), &options).unwrap();
    with_gpu(|ctx: &Arc<Context>| {
        let renderer = PrimalRenderer::new(GpuScene::new(ctx, &scene).unwrap()).unwrap();
        let gs = &renderer.scene;
        gs.set_theta(gs.layout.reference()).unwrap();
        gs.set_frame(0).unwrap();
        let targets = vec![renderer.render(0, 4, 0x7A46_E701, |_, _| {}).unwrap()];
        gs.set_theta(gs.layout.initial()).unwrap();
        let ops = BufferOps::new(ctx).unwrap();
        let grad = Buffer::zeroed::<f32>(ctx, "grad", gs.layout.len, MemoryKind::Device).unwrap();
        let pass = GradientPass::new(
            gs,
            &ops,
            &GradientInputs {
                targets: &targets,
                loss: Loss::L2,
                spp: 1,
                primal_spp: 1,
                seed: 1,
                theta: &gs.theta,
                theta_prev: None,
                grad: &grad,
                grad_half: None,
            },
        )
        .unwrap();
        let mut cmd = CommandBuffer::new(ctx, "gradient").unwrap();
        cmd.record(|rec| pass.record(rec, gs, &ops)).unwrap();
        let iterate = |cmd: &mut CommandBuffer, frames: std::ops::Range<u32>| {
            for frame in frames {
                gs.set_frame(frame).unwrap();
                cmd.submit_and_wait().unwrap();
            }
        };
        // Warm-up: first submissions may fill driver and validation-layer caches.
        iterate(&mut cmd, 0..50);
        let (device, host) = (device_memory(ctx), resident_pages());
        iterate(&mut cmd, 50..1050);
        let (device_after, host_after) = (device_memory(ctx), resident_pages());
        eprintln!("memory: device {device:?} → {device_after:?} (allocations, bytes); host {host} → {host_after} resident pages");
        assert_eq!(device_after, device, "device allocations (count, bytes) changed over 1000 iterations");
        assert!(host_after <= host + HOST_SLACK_PAGES, "resident memory grew by {} pages over 1000 iterations", host_after - host);
        let g: Vec<f32> = grad.read().unwrap();
        assert!(g.iter().all(|v| v.is_finite()) && g.iter().any(|&v| v != 0.0), "the loop must have computed gradients: {g:?}");
    });
}
