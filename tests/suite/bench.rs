//! The scene bench on the Cornell box: every reported figure is finite and positive, and the
//! figures agree with each other and with the scene.

use crate::common;

use common::{with_gpu, with_gpu_options};
use vkinverse::scene::Scene;

fn finite_positive(what: &str, v: f64) {
    assert!(v.is_finite() && v > 0.0, "{what} = {v}");
}

#[test]
fn scene_bench_on_cornell_is_consistent() {
    let scene = Scene::load(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/cornell/scene.toml")).unwrap();
    // Two iterations: the medians are means, so per-pass sums compare with the total.
    let b = with_gpu(|ctx| vkinverse::bench::scene_bench(&common::device(ctx), &scene, 2, 1 << 16, std::time::Duration::ZERO).unwrap());
    // Without a warm-up time, one untimed round: the one that compiles the pipelines.
    assert_eq!(b.warm_up.rounds, 1);

    // Every scope is named after its kernel, within its group of passes.
    let names: Vec<String> = b.passes.iter().map(|p| format!("{}/{}", p.group, p.name)).collect();
    assert_eq!(
        names,
        [
            "gradient/trace_primal",
            "gradient/loss",
            "gradient/trace_adjoint",
            "finite_difference/trace_fd_primal",
            "finite_difference/loss",
            "finite_difference/trace_fd_adjoint",
            "finite_difference_two_trace/trace_primal",
            "finite_difference_two_trace/loss",
            "finite_difference_two_trace/trace_adjoint",
            "finite_difference_two_trace/sub",
            "optimiser/optim_meta",
            "optimiser/optim_adam",
            "optimiser/copy",
        ]
    );
    for p in &b.passes {
        finite_positive(&p.name, p.median_ms);
        for rate in [p.rays_per_s, p.params_per_s, p.gb_per_s].into_iter().flatten() {
            finite_positive(&p.name, rate);
        }
    }
    let sum: f64 = b.passes.iter().map(|p| p.median_ms).sum();
    assert!(sum <= b.iteration_ms * (1.0 + 1e-9), "passes sum to {sum} ms, the iteration took {} ms", b.iteration_ms);
    assert_eq!(b.passes[0].rays_per_s, Some(b.rays.rays_per_s));
    assert_eq!(b.passes[10].params_per_s.is_some(), b.parameters > 0);
    // The fused finite-difference sample is the sum of its passes.
    let fd: f64 = b.passes[3..6].iter().map(|p| p.median_ms).sum();
    assert!((b.ratios.finite_difference_ms - fd).abs() <= 0.5 * fd, "{} ms against passes summing to {fd} ms", b.ratios.finite_difference_ms);

    // Each sample casts a camera ray and at most one extension and one shadow ray per
    // further vertex.
    let samples = (b.width * b.height) as u64 * b.sensors as u64 * b.rays.spp as u64;
    let max_depth: u64 = b.specialisation.iter().find(|c| c.name == "MAX_DEPTH").unwrap().value.parse().unwrap();
    assert!(b.rays.rays >= samples, "{} rays for {samples} samples", b.rays.rays);
    assert!(b.rays.rays <= samples * (2 * max_depth - 1), "{} rays for {samples} samples", b.rays.rays);
    finite_positive("rays/s", b.rays.rays_per_s);

    // The integrator's constants, then each scene feature's (src/render/features).
    let spec: Vec<&str> = b.specialisation.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(
        spec,
        [
            "MAX_DEPTH",
            "RR_DEPTH",
            "HIDE_EMITTERS",
            "HAS_TEXTURES",
            "CONST_BASE",
            "HAS_PRINCIPLED",
            "HAS_DIELECTRICS",
            "HAS_ROUGH_DIELECTRICS",
            "HAS_CONDUCTORS",
            "HAS_PLASTICS",
            "HAS_DELTA_LIGHTS",
            "HAS_ENVIRONMENT",
            "ENVIRONMENT_SAMPLED",
            "NUM_EMITTERS",
            "HAS_EMISSION_TEXTURES",
            "SPHERE_EMITTERS",
            "HAS_NORMALS",
            "HAS_NORMAL_MAPS",
            "HAS_ALPHA_MASKS",
            "HAS_UV1",
            "BVH_STACK_REGISTERS",
            "HAS_MEDIA",
            "MAJORANT_GRID",
            "MEDIUM_BOUNDARY"
        ]
    );
    let g = &b.specialisation_gain;
    finite_positive("generic trace_primal", g.generic_ms);
    finite_positive("specialisation gain", g.gain);
    assert_eq!(g.specialised_ms, b.passes[0].median_ms);
    // Same paths, same radiance: the variants differ in speed only.
    assert!(g.generic_image_rel_diff < 1e-4, "generic build renders a different image: {}", g.generic_image_rel_diff);
    assert!(g.count_image_rel_diff < 1e-4, "counting build renders a different image: {}", g.count_image_rel_diff);
    // Texel fetches and image loads read the same bits: the same image, bit for bit.
    finite_positive("sampled trace_primal", g.sampled_ms);
    assert_eq!(g.sampled_gain, g.sampled_ms / g.specialised_ms);
    assert_eq!(g.sampled_image_rel_diff, 0.0, "texel fetches render a different image");

    let r = &b.ratios;
    assert_eq!(r.spp, b.fd_spp);
    for (what, v) in [
        ("proportional", r.proportional_ms),
        ("finite difference", r.finite_difference_ms),
        ("primal", r.primal_ms),
        ("adjoint", r.adjoint_ms),
        ("fd / proportional", r.fd_over_proportional),
        ("adjoint / primal", r.adjoint_over_primal),
    ] {
        finite_positive(what, v);
    }
    assert!(r.primal_ms + r.adjoint_ms <= r.proportional_ms * (1.0 + 1e-9));

    assert_eq!(b.bvh.rays, (b.width * b.height * 16) as u64);
    finite_positive("closest hit Mrays/s", b.bvh.closest_mrays_per_s);
    finite_positive("any hit Mrays/s", b.bvh.any_mrays_per_s);
    finite_positive("memory", b.memory_bytes as f64);

    // Per iteration the host writes the 4-byte frame counter and reads one report: the
    // 4-byte loss of each sensor, the optimiser's diagnostics (one record per optimised
    // parameter), the carried image's 20-byte state of each sensor (meta's defaults carry
    // it) and θ, which the iteration copies on the device into one host-visible buffer. Nothing is allocated, and nothing is staged or submitted besides the iteration,
    // also where device memory is not mapped (CI runs the suite once so).
    let t = &b.transfer;
    let diag_bytes = (scene.optimise.params.len() * std::mem::size_of::<vkinverse::shared::DiagRecord>()) as f64;
    assert_eq!(t.upload_bytes, 4.0, "{t:?}");
    assert_eq!(t.readback_bytes, 4.0 * b.sensors as f64 + diag_bytes + 20.0 * b.sensors as f64 + 4.0 * b.parameters as f64, "{t:?}");
    assert_eq!(t.buffers_created, 0, "{t:?}");
    assert_eq!((t.staged_bytes, t.staged_submissions), (0.0, 0.0), "{t:?}");

    assert_eq!(b.optimisers.elements, 1 << 16);
    let opt: Vec<&str> = b.optimisers.passes.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(opt, ["optim_meta", "optim_adam", "copy", "copy_vec4"]);
    for p in &b.optimisers.passes {
        finite_positive(&p.name, p.gb_per_s);
        finite_positive(&p.name, p.params_per_s);
        finite_positive(&p.name, p.ratio_to_copy);
        finite_positive(&p.name, p.ratio_to_copy_vec4);
    }
    assert_eq!(b.optimisers.passes[3].ratio_to_copy_vec4, 1.0);

    let json = serde_json::to_value(&b).unwrap();
    for key in ["passes", "rays", "specialisation", "specialisation_gain", "ratios", "bvh", "memory_bytes", "optimisers"] {
        assert!(json.get(key).is_some(), "JSON lacks {key}");
    }
}

/// On a scene whose medium scatters, the bench's builds of trace_primal (unspecialised,
/// counting, texel fetches) are its scattering builds too: each renders the specialised
/// build's image (before, they left the scattering out and their timings compared
/// another integrator).
#[test]
fn scene_bench_on_a_scattering_medium_compares_like_builds() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/cloud/scene.toml");
    let options = vkinverse::scene::LoadOptions { film: Some(vkinverse::scene::Film { width: 12, height: 12 }), max_depth: None };
    let scene = Scene::load_with(path, &options).unwrap();
    assert!(scene.media[0].scatters());
    let b = with_gpu(|ctx| vkinverse::bench::scene_bench(&common::device(ctx), &scene, 1, 1 << 12, std::time::Duration::ZERO).unwrap());
    let g = &b.specialisation_gain;
    assert!(g.generic_image_rel_diff < 1e-4, "generic build renders a different image: {}", g.generic_image_rel_diff);
    assert!(g.count_image_rel_diff < 1e-4, "counting build renders a different image: {}", g.count_image_rel_diff);
    assert_eq!(g.sampled_image_rel_diff, 0.0, "texel fetches render a different image");
}

#[test]
fn bvh_layout_bench_on_cornell_is_consistent() {
    let scene = Scene::load(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/cornell/scene.toml")).unwrap();
    let b = with_gpu(|ctx| vkinverse::bench::layout_bench(&common::device(ctx), &scene, 2).unwrap());
    let names: Vec<&str> = b.layouts.iter().map(|l| l.layout.as_str()).collect();
    assert_eq!(names, ["binary", "wide", "cw8"]);
    for l in &b.layouts {
        for (what, v) in [
            ("closest", l.closest_mrays_per_s),
            ("any", l.any_mrays_per_s),
            ("primal", l.primal_ms),
            ("primal rays", l.primal_mrays_per_s),
            ("closest ratio", l.closest_over_binary),
            ("any ratio", l.any_over_binary),
            ("primal ratio", l.primal_over_binary),
        ] {
            finite_positive(&format!("{} {what}", l.layout), v);
        }
        // Every layout traces the same rays to the same hits as the binary one.
        assert_eq!(l.any_hit_disagreements, 0, "{}", l.layout);
        assert!(l.primal_image_rel_diff <= 1e-4, "{}: primal images differ by {}", l.layout, l.primal_image_rel_diff);
    }
    assert_eq!(b.layouts[0].closest_over_binary, 1.0);
    assert!(b.table().contains("cw8"));
}

/// The buffer bench at a small size: every kernel it reports, the gathers through a storage
/// buffer and a texel buffer among them, has a finite positive time and rate.
#[test]
fn buffer_bench_reports_every_kernel() {
    let b = with_gpu(|ctx| vkinverse::bench::buffer_bench(&common::device(ctx), 1 << 14, 1).unwrap());
    let names: Vec<&str> = b.kernels.iter().map(|k| k.name.as_str()).collect();
    for wanted in ["copy", "copy_vec4", "fill", "scale_add", "reduce_sum", "gather", "gather_texel"] {
        assert!(names.contains(&wanted), "{wanted} missing from {names:?}");
    }
    for k in &b.kernels {
        finite_positive(&k.name, k.median_ms);
        finite_positive(&k.name, k.gb_per_s);
    }
    let copy = b.kernels.iter().find(|k| k.name == "copy").unwrap();
    assert!((copy.ratio_to_copy - 1.0).abs() < 1e-12);
}

/// The optimiser passes' bench submits each timed round on its own: with the fence's
/// timeout set to three times one round's time (at least 2 s, above the warm-up's pipeline
/// compilation), twice the timeout's worth of rounds still finishes, where those rounds in
/// one submission would run past it. (The default `vkinverse bench` times 16 M parameters,
/// about 13 s a round on lavapipe here: ten rounds in one submission ran into the 120 s
/// timeout and were reported as a hung device.)
#[test]
fn optimiser_bench_rounds_stay_within_the_timeout() {
    let elements = 1 << 20;
    let round = with_gpu(|ctx| vkinverse::bench::optimiser_bandwidth(ctx, elements, 1).unwrap());
    let round_ms: f64 = round.passes.iter().map(|p| p.median_ms).sum();
    finite_positive("one round", round_ms);
    let timeout_ms = (3.0 * round_ms).max(2000.0);
    let rounds = (2.0 * timeout_ms / round_ms).ceil() as u32;
    let options = vkinverse::gpu::ContextOptions { timeout: Some(std::time::Duration::from_secs_f64(timeout_ms * 1e-3)), ..common::options() };
    let b = with_gpu_options(options, |ctx| vkinverse::bench::optimiser_bandwidth(ctx, elements, rounds))
        .unwrap_or_else(|e| panic!("{rounds} rounds of {round_ms:.0} ms with a {timeout_ms:.0} ms timeout: {e}"));
    assert_eq!(b.iterations, rounds);
    for p in &b.passes {
        finite_positive(&p.name, p.median_ms);
    }
}

/// The medium bench on a small grid and film: every pass has a finite positive time, the
/// voxel lookups follow from the host's step count (steps × 8 taps × 2 grids × states ×
/// marches), a ray's steps are bounded by the box's diagonal, and the optimiser passes run
/// over a θ of the grid's size, against the float4 copy.
#[test]
fn media_bench_reports_every_pass() {
    let options = vkinverse::bench::MediaOptions { grids: vec![12], films: vec![16], iterations: 2, ..Default::default() };
    let b = with_gpu(|ctx| vkinverse::bench::media_bench(&common::device(ctx), &options).unwrap());
    assert_eq!(b.cases.len(), 1);
    let c = &b.cases[0];
    assert_eq!((c.grid, c.width, c.height, c.parameters), (12, 16, 16, 4 * 12 * 12 * 12));
    let names: Vec<String> = c.passes.iter().map(|p| format!("{}/{}", p.group, p.name)).collect();
    assert_eq!(
        names,
        [
            "gradient/trace_primal",
            "gradient/loss",
            "gradient/trace_adjoint",
            "finite_difference/trace_fd_primal",
            "finite_difference/loss",
            "finite_difference/trace_fd_adjoint"
        ]
    );
    // Half a voxel of a 2-wide box of 12 voxels.
    assert!((c.step - 2.0 / 12.0 * 0.5).abs() < 1e-6, "step {}", c.step);
    assert!(c.crossing_fraction > 0.5 && c.crossing_fraction <= 1.0, "{}", c.crossing_fraction);
    // A crossing ray takes at least one step and at most the diagonal's.
    let most = (2.0 * 3f64.sqrt() / c.step as f64).ceil();
    assert!(c.steps_per_crossing_ray >= 1.0 && c.steps_per_crossing_ray <= most, "{} steps (at most {most})", c.steps_per_crossing_ray);
    assert!((c.steps_per_ray - c.steps_per_crossing_ray * c.crossing_fraction).abs() < 1e-9 * c.steps_per_ray.max(1.0));
    let primal_lookups = c.passes[0].voxel_lookups.unwrap();
    let film_steps = c.steps_per_ray * 256.0;
    assert_eq!(primal_lookups, film_steps.round() as u64 * 16);
    for (i, factor) in [(2, 2), (3, 2), (5, 4)] {
        assert_eq!(c.passes[i].voxel_lookups, Some(primal_lookups * factor), "{}", names[i]);
    }
    for p in &c.passes {
        finite_positive(&p.name, p.median_ms);
        assert_eq!(p.voxel_lookups.is_some(), p.name != "loss");
        assert_eq!(p.spp, p.voxel_lookups.map(|_| 1));
        if let Some(rate) = p.lookups_per_s {
            finite_positive(&p.name, rate);
        }
    }
    finite_positive("adjoint / primal", c.adjoint_over_primal);
    finite_positive("fd / gradient", c.fd_over_gradient);
    assert_eq!(b.optimisers.elements, 4 * 12 * 12 * 12);
    let opt: Vec<&str> = b.optimisers.passes.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(opt, ["optim_meta", "optim_adam", "copy", "copy_vec4"]);
    for p in &b.optimisers.passes {
        finite_positive(&p.name, p.ratio_to_copy_vec4);
    }
    let table = b.table();
    assert!(table.contains("12^3") && table.contains("trace_fd_adjoint") && table.contains("vs vec4"), "{table}");
    let json = serde_json::to_value(&b).unwrap();
    assert!(json["cases"][0]["passes"][0].get("lookups_per_s").is_some());
}

/// `vkinverse bench --media`'s arguments are checked before anything is measured (the
/// measurement itself is media_bench_reports_every_pass's: a second run would double the
/// pipelines' compilation time on lavapipe).
#[test]
fn bench_media_arguments_are_checked() {
    common::binary::vkinverse_err(&["bench", "--media-grids", "8"], &["--media"]);
    common::binary::vkinverse_err(&["bench", "--media", "--media-grids", "1"], &["grid side 1"]);
    common::binary::vkinverse_err(&["bench", "--media", "--media-films", "0"], &["film side 0"]);
}
