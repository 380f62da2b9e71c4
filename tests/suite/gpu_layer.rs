//! The GPU layer on lavapipe: kernels against CPU results, layouts by reflection, the
//! barrier hazard check, timestamps and typed errors.

use crate::common;

use common::with_gpu;
use vkinverse::gpu::{
    check_features, Access, Buffer, CommandBuffer, ComputePipeline, Context, ContextOptions, DeviceFeatures, GpuError, MemoryKind, Profiler, Recorder,
    SpecValue,
};
use vkinverse::ops::BufferOps;

/// Sizes around the workgroup size (256) and reduce chunk (1024), including 0 and 1.
const SIZES: [usize; 9] = [0, 1, 7, 255, 256, 257, 1023, 1025, 100_003];

fn data(n: usize, seed: u32) -> Vec<f32> {
    // A small LCG: deterministic, values in [-1, 1).
    let mut s = seed.wrapping_mul(747796405).wrapping_add(1);
    (0..n)
        .map(|_| {
            s = s.wrapping_mul(1664525).wrapping_add(1013904223);
            (s >> 8) as f32 / (1u32 << 23) as f32 - 1.0
        })
        .collect()
}

#[test]
fn fill_copy_scale_add_match_cpu() {
    with_gpu(|ctx| {
        let ops = BufferOps::new(ctx).unwrap();
        for &n in &SIZES {
            let src = data(n, n as u32);
            let a = Buffer::from_slice(ctx, "a", &src, MemoryKind::Device).unwrap();
            let b = Buffer::zeroed::<f32>(ctx, "b", n, MemoryKind::Device).unwrap();
            let c = Buffer::zeroed::<f32>(ctx, "c", n, MemoryKind::Device).unwrap();
            let mut cmd = CommandBuffer::new(ctx, "t").unwrap();
            cmd.record(|rec| {
                ops.fill(rec, &c, 2.5)?;
                ops.copy(rec, &a, &b)?;
                rec.barrier(&b, Access::ComputeWrite, Access::ComputeReadWrite)?;
                ops.scale_add(rec, &b, -3.0, 0.5)?;
                Ok(())
            })
            .unwrap();
            cmd.submit_and_wait().unwrap();
            let got_b: Vec<f32> = b.read().unwrap();
            let got_c: Vec<f32> = c.read().unwrap();
            assert_eq!(got_b.len(), n);
            for i in 0..n {
                // A device may fuse the multiply and add into one rounding (NVIDIA does;
                // lavapipe rounds twice): either result is exact for its arithmetic.
                let (twice, fused) = (-3.0 * src[i] + 0.5, (-3.0f32).mul_add(src[i], 0.5));
                assert!(got_b[i] == twice || got_b[i] == fused, "scale_add n={n} i={i}: {} is neither {twice} nor {fused}", got_b[i]);
                assert_eq!(got_c[i], 2.5, "fill n={n} i={i}");
            }
        }
    });
}

#[test]
fn reductions_match_cpu() {
    with_gpu(|ctx| {
        let ops = BufferOps::new(ctx).unwrap();
        for &n in &SIZES {
            let src = data(n, 7 + n as u32);
            let a = Buffer::from_slice(ctx, "a", &src, MemoryKind::Device).unwrap();
            let sum: f64 = src.iter().map(|&x| x as f64).sum();
            let sumsq: f64 = src.iter().map(|&x| (x as f64) * (x as f64)).sum();
            let abs: f64 = src.iter().map(|&x| (x as f64).abs()).sum();
            let got = ops.sum(&a, false).unwrap() as f64;
            let got_sq = ops.sum(&a, true).unwrap() as f64;
            // f32 tree summation: error bounded by a few ulps times log2(n) of the sum of
            // magnitudes.
            let tol = 1e-6 * abs.max(1.0) * (n.max(2) as f64).log2();
            assert!((got - sum).abs() <= tol, "sum n={n}: {got} vs {sum}");
            assert!((got_sq - sumsq).abs() <= tol, "sumsq n={n}: {got_sq} vs {sumsq}");
        }
    });
}

#[test]
fn dispatch_folds_more_than_65535_workgroups() {
    with_gpu(|ctx| {
        // 64-thread workgroups: 65535 * 64 + 100 elements need a second grid axis.
        let n = 65535 * 64 + 100;
        let fill = ComputePipeline::new(ctx, "fill", &[("local_size_x", SpecValue::U32(64))]).unwrap();
        assert_eq!(fill.local_size(), [64, 1, 1]);
        let buf = Buffer::zeroed::<f32>(ctx, "big", n, MemoryKind::Device).unwrap();
        let group = fill.bind(&[("Dst", &buf)]).unwrap();
        let push = vkinverse::kernels::FillPush { n: n as u32, value: 7.0 };
        let mut cmd = CommandBuffer::new(ctx, "t").unwrap();
        cmd.record(|rec| rec.dispatch_linear(&fill, &group, &push, n as u64)).unwrap();
        cmd.submit_and_wait().unwrap();
        let got: Vec<f32> = buf.read().unwrap();
        assert!(got.iter().all(|&v| v == 7.0), "an element was not written");
    });
}

#[test]
fn resubmitting_a_recording_repeats_its_work() {
    with_gpu(|ctx| {
        let ops = BufferOps::new(ctx).unwrap();
        let x = Buffer::from_slice(ctx, "x", &[1.0f32; 300], MemoryKind::Device).unwrap();
        let mut cmd = CommandBuffer::new(ctx, "t").unwrap();
        cmd.record(|rec| ops.scale_add(rec, &x, 2.0, 1.0)).unwrap();
        for _ in 0..3 {
            cmd.submit_and_wait().unwrap();
        }
        // 1 -> 3 -> 7 -> 15
        assert!(x.read::<f32>().unwrap().iter().all(|&v| v == 15.0));
    });
}

#[test]
fn struct_layouts_match_reflection() {
    use vkinverse::shared::ProbeStruct;
    let rust = [
        ("a", std::mem::offset_of!(ProbeStruct, a)),
        ("b", std::mem::offset_of!(ProbeStruct, b)),
        ("c", std::mem::offset_of!(ProbeStruct, c)),
        ("d", std::mem::offset_of!(ProbeStruct, d)),
    ];
    common::check_layout("layout_probe", "ProbeStruct", &rust, std::mem::size_of::<ProbeStruct>());
}

/// Each dispatch, copy and fill gets the barrier its buffers' previous use needs, and no
/// other: read after write and write after read one each, reads after reads none. The
/// validation layer's synchronization check (on in every test) fails the test on any
/// barrier missing, and the results show the ordering. An unordered batch derives none
/// between its own commands and refuses a dependency inside it; a hand-written barrier is
/// checked against the recorded access and counts for the derived one.
#[test]
fn barriers_are_derived_from_each_buffers_previous_use() {
    with_gpu(|ctx| {
        let ops = BufferOps::new(ctx).unwrap();
        let a = Buffer::zeroed::<f32>(ctx, "a", 100, MemoryKind::Device).unwrap();
        let b = Buffer::zeroed::<f32>(ctx, "b", 100, MemoryKind::Device).unwrap();
        let c = Buffer::zeroed::<f32>(ctx, "c", 100, MemoryKind::Device).unwrap();
        let mut cmd = CommandBuffer::new(ctx, "t").unwrap();
        // Records `f` and returns the barriers the recording holds.
        let barriers = |cmd: &mut CommandBuffer, f: &dyn Fn(&mut Recorder) -> vkinverse::gpu::Result<()>| -> u32 {
            let mut n = 0;
            cmd.record(|rec| {
                f(rec)?;
                n = rec.barrier_count();
                Ok(())
            })
            .unwrap();
            cmd.submit_and_wait().unwrap();
            n
        };

        // Read after write, twice: a fill, then a chain of copies that read what came before.
        let n = barriers(&mut cmd, &|rec| {
            ops.fill(rec, &a, 3.0)?;
            ops.copy(rec, &a, &b)?;
            ops.copy(rec, &b, &c)
        });
        assert_eq!(n, 2, "a and b, each read after its write");
        assert_eq!(c.read::<f32>().unwrap(), vec![3.0f32; 100]);

        // Write after read: the fill waits for the copy that reads a.
        let n = barriers(&mut cmd, &|rec| {
            ops.copy(rec, &a, &b)?;
            ops.fill(rec, &a, 5.0)
        });
        assert_eq!(n, 1);
        assert_eq!((b.read::<f32>().unwrap()[0], a.read::<f32>().unwrap()[0]), (3.0, 5.0), "the copy read a before the fill");

        // Reads after reads need nothing.
        assert_eq!(
            barriers(&mut cmd, &|rec| {
                ops.copy(rec, &a, &b)?;
                ops.copy(rec, &a, &c)
            }),
            0
        );

        // A write made visible to compute reads is not visible to a transfer read: the
        // transfer copy gets a barrier of its own from the write.
        let n = barriers(&mut cmd, &|rec| {
            ops.fill(rec, &b, 2.0)?;
            ops.copy(rec, &b, &c)?;
            rec.copy(&b, &a, 400)
        });
        assert_eq!(n, 2, "b to compute reads, then b to transfer reads (a is not touched before in this recording)");
        assert_eq!(a.read::<f32>().unwrap(), vec![2.0f32; 100]);

        // A hand-written barrier covers the access it declares; none is derived after it.
        assert_eq!(
            barriers(&mut cmd, &|rec| {
                ops.fill(rec, &b, 4.0)?;
                rec.barrier(&b, Access::ComputeWrite, Access::ComputeRead)?;
                ops.copy(rec, &b, &c)
            }),
            1
        );
        assert_eq!(c.read::<f32>().unwrap(), vec![4.0f32; 100]);

        // An unordered batch: copies into disjoint halves of one buffer need no barrier
        // between them; the read of a after the batch waits for both, and the write of c
        // for the batch's read of it.
        let n = barriers(&mut cmd, &|rec| {
            rec.unordered(|rec| {
                rec.copy_range(&b, 0, &a, 0, 200)?;
                rec.copy_range(&c, 200, &a, 200, 200)
            })?;
            ops.copy(rec, &a, &c)
        });
        assert_eq!(n, 2, "a read and c written after the batch, nothing inside it");
        assert_eq!(c.read::<f32>().unwrap(), vec![4.0f32; 100]);
        // A dependency inside a batch has nothing to order it: refused while recording.
        let err = cmd
            .record(|rec| {
                rec.unordered(|rec| {
                    ops.fill(rec, &a, 1.0)?;
                    ops.copy(rec, &a, &b)
                })
            })
            .unwrap_err();
        assert!(matches!(err, GpuError::Hazard { ref buffer, previous: Access::ComputeWrite, now: Access::ComputeRead, .. } if buffer == "a"), "{err}");

        // A barrier that misdeclares the previous access is caught in debug builds.
        if cfg!(debug_assertions) {
            let err = cmd
                .record(|rec| {
                    ops.copy(rec, &a, &b)?;
                    rec.barrier(&b, Access::TransferWrite, Access::ComputeRead)?;
                    Ok(())
                })
                .unwrap_err();
            assert!(matches!(err, GpuError::BarrierMismatch { .. }), "{err}");
        }
    });
}

/// With a profiler attached, a dispatch outside any named scope is timed in a scope named
/// after its kernel (consecutive dispatches of one kernel in one scope), and a named scope
/// takes the dispatches inside it.
#[test]
fn attached_profilers_time_every_pass_by_kernel() {
    with_gpu(|ctx| {
        let ops = BufferOps::new(ctx).unwrap();
        let a = Buffer::zeroed::<f32>(ctx, "a", 1 << 16, MemoryKind::Device).unwrap();
        let b = Buffer::zeroed::<f32>(ctx, "b", 1 << 16, MemoryKind::Device).unwrap();
        let mut prof = Profiler::new(ctx, Profiler::SCOPES).unwrap();
        let mut cmd = CommandBuffer::new(ctx, "t").unwrap();
        cmd.record_profiled(&mut prof, |rec| {
            ops.fill(rec, &a, 1.0)?;
            ops.fill(rec, &b, 2.0)?;
            ops.copy(rec, &a, &b)?;
            rec.scope("named", |rec| {
                ops.fill(rec, &a, 3.0)?;
                ops.copy(rec, &a, &b)
            })
        })
        .unwrap();
        cmd.submit_and_wait().unwrap();
        let names: Vec<(String, usize)> = prof.results().unwrap().into_iter().map(|t| (t.name, t.depth)).collect();
        let want = [("fill", 0), ("copy", 0), ("named", 0)].map(|(n, d)| (n.to_string(), d));
        assert_eq!(names, want);
        assert_eq!(b.read::<f32>().unwrap()[0], 3.0);
        // A scope left open is an error.
        let err = cmd.record_profiled(&mut prof, |rec| rec.begin_scope("open")).unwrap_err();
        assert!(err.to_string().contains("never ended"), "{err}");
    });
}

#[test]
fn timestamp_scopes_are_named_and_nest() {
    with_gpu(|ctx| {
        let ops = BufferOps::new(ctx).unwrap();
        let a = Buffer::zeroed::<f32>(ctx, "a", 1 << 18, MemoryKind::Device).unwrap();
        let b = Buffer::zeroed::<f32>(ctx, "b", 1 << 18, MemoryKind::Device).unwrap();
        let mut prof = Profiler::new(ctx, 8).unwrap();
        let mut cmd = CommandBuffer::new(ctx, "t").unwrap();
        cmd.record(|rec| {
            prof.reset(rec);
            prof.scope(rec, "outer", |rec, prof| {
                prof.scope(rec, "fill", |rec, _| {
                    ops.fill(rec, &a, 1.0)?;
                    Ok(())
                })?;
                rec.barrier(&a, Access::ComputeWrite, Access::ComputeRead)?;
                prof.scope(rec, "copy", |rec, _| {
                    ops.copy(rec, &a, &b)?;
                    Ok(())
                })
            })
        })
        .unwrap();
        cmd.submit_and_wait().unwrap();
        let t = prof.results().unwrap();
        let names: Vec<_> = t.iter().map(|s| (s.name.as_str(), s.depth)).collect();
        assert_eq!(names, [("outer", 0), ("fill", 1), ("copy", 1)]);
        assert!(t.iter().all(|s| s.ms >= 0.0 && s.ms.is_finite()));
        assert!(t[1].ms > 0.0 && t[2].ms > 0.0, "work takes time: {t:?}");
        // The outer scope contains both inner ones (and the barrier between them).
        assert!(t[0].ms + 1e-6 >= t[1].ms + t[2].ms, "{t:?}");
        assert!((Profiler::total_ms(&t, "fill") - t[1].ms).abs() < 1e-12);
        // Too many scopes is an error, not a panic or overflow.
        let mut small = Profiler::new(ctx, 1).unwrap();
        let err = cmd
            .record(|rec| {
                small.reset(rec);
                small.begin(rec, "a")?;
                small.end(rec)?;
                small.begin(rec, "b")
            })
            .unwrap_err();
        assert!(matches!(err, GpuError::Profiler(_)), "{err}");
    });
}

#[test]
fn typed_errors() {
    // A device lacking a feature is refused with the feature named.
    let mut f = DeviceFeatures {
        vulkan_1_3: true,
        scalar_block_layout: true,
        synchronization2: true,
        maintenance4: true,
        float32_atomic_add: true,
        subgroup_arithmetic: true,
        timestamps: true,
    };
    assert!(check_features("dev", &f).is_ok());
    f.float32_atomic_add = false;
    let e = check_features("dev", &f).unwrap_err();
    assert!(matches!(e, GpuError::MissingFeature { feature, .. } if feature.contains("shaderBufferFloat32AtomicAdd")));

    let e = Context::new(&ContextOptions { device: Some("no such device".into()), ..Default::default() }).err().unwrap();
    assert!(matches!(e, GpuError::DeviceNotFound(_)), "{e}");

    with_gpu(|ctx| {
        let copy = ComputePipeline::new(ctx, "copy", &[]).unwrap();
        let a = Buffer::zeroed::<f32>(ctx, "a", 4, MemoryKind::Device).unwrap();
        let e = copy.bind(&[("Src", &a), ("Dts", &a)]).err().unwrap();
        assert!(matches!(e, GpuError::UnknownBinding { ref name, .. } if name == "Dts"), "{e}");
        assert!(e.to_string().contains("Dst"), "the message lists the known names: {e}");
        let e = copy.bind(&[("Src", &a)]).err().unwrap();
        assert!(matches!(e, GpuError::UnboundBinding { ref name, .. } if name == "Dst"), "{e}");
        let group = copy.bind(&[("Src", &a), ("Dst", &a)]).unwrap();
        let mut cmd = CommandBuffer::new(ctx, "t").unwrap();
        let wrong_size = vkinverse::kernels::FillPush { n: 4, value: 0.0 };
        let e = cmd.record(|rec| rec.dispatch_linear(&copy, &group, &wrong_size, 4)).unwrap_err();
        assert!(matches!(e, GpuError::PushConstantSize { expected: 4, got: 8, .. }), "{e}");
        // The right size with another member is refused too, naming both layouts.
        let e = cmd.record(|rec| rec.dispatch_linear(&copy, &group, &vkinverse::kernels::Count4Push { n4: 1 }, 4)).unwrap_err();
        assert!(matches!(e, GpuError::PushLayout { .. }) && e.to_string().contains("n@0") && e.to_string().contains("n4@0"), "{e}");
        let e = ComputePipeline::new(ctx, "copy", &[("NOPE", SpecValue::U32(1))]).err().unwrap();
        assert!(matches!(e, GpuError::UnknownSpecConstant { .. }), "{e}");
        let e = ComputePipeline::new(ctx, "reduce", &[("SQUARE", SpecValue::U32(1))]).err().unwrap();
        assert!(matches!(e, GpuError::SpecConstantType { .. }), "{e}");
        let e = ComputePipeline::new(ctx, "no_such_kernel", &[]).err().unwrap();
        assert!(matches!(e, GpuError::UnknownKernel(_)), "{e}");
        // A buffer may be as long as the longer of the two ranges it can be bound by.
        let max = ctx.info().max_storage_buffer_range.max(ctx.info().max_texel_buffer_bytes());
        let e = Buffer::new(ctx, "huge", max + 4, MemoryKind::Device).err().unwrap();
        assert!(matches!(e, GpuError::BufferTooLarge { .. }), "{e}");
        let e = a.write(&[0f32; 5]).unwrap_err();
        assert!(matches!(e, GpuError::BufferAccess { .. }), "{e}");
    });
}

/// A storage-buffer binding sees at most the device's storage-buffer range: binding a
/// longer buffer whole is refused, naming the buffer, the kernel's binding and the range;
/// with its storage extent set within the range the same buffer binds, and the kernel
/// writes only that extent.
#[test]
fn storage_bindings_stay_within_the_storage_range() {
    let options = ContextOptions { storage_buffer_range_cap: Some(32), ..common::options() };
    common::with_gpu_options(options, |ctx| {
        let copy = ComputePipeline::new(ctx, "copy", &[]).unwrap();
        let src = Buffer::from_slice(ctx, "src", &[1.0f32; 16], MemoryKind::Device).unwrap();
        let dst = Buffer::from_slice(ctx, "dst", &[0.0f32; 16], MemoryKind::Device).unwrap();
        let e = copy.bind(&[("Src", &src), ("Dst", &dst)]).err().unwrap();
        assert!(matches!(e, GpuError::BufferTooLarge { max: 32, .. }), "{e}");
        assert!(e.to_string().contains("storage buffer 'Src' of kernel 'copy'") && e.to_string().contains("storage-buffer range of 32 bytes"), "{e}");
        src.set_storage_extent(32);
        dst.set_storage_extent(32);
        let group = copy.bind(&[("Src", &src), ("Dst", &dst)]).unwrap();
        let mut cmd = CommandBuffer::new(ctx, "t").unwrap();
        cmd.record(|rec| rec.dispatch_linear(&copy, &group, &vkinverse::kernels::CountPush { n: 8 }, 8)).unwrap();
        cmd.submit_and_wait().unwrap();
        let out: Vec<f32> = dst.read().unwrap();
        assert_eq!(&out[..8], &[1.0; 8]);
        assert_eq!(&out[8..], &[0.0; 8], "nothing beyond the storage extent is written");
    });
}

#[test]
fn leak_report_sees_live_allocations() {
    with_gpu(|ctx| {
        let a = Buffer::new(ctx, "still alive", 64, MemoryKind::Upload).unwrap();
        let live = ctx.live_allocations();
        assert!(live.iter().any(|(name, _)| name == "still alive"), "{live:?}");
        drop(a);
        assert!(ctx.live_allocations().is_empty());
    });
}

#[test]
fn validation_layer_reports_misuse() {
    // The harness relies on the messenger: show that it does collect a real error, here
    // an invalid SPIR-V module.
    let ctx = common::context();
    assert!(ctx.validation_enabled());
    let spirv = vkinverse::gpu::shaders::get("fill").unwrap();
    let mut bad = spirv.to_vec();
    // Flip the SPIR-V into an invalid module: zero the bound word (header word 3).
    bad[12..16].copy_from_slice(&0u32.to_le_bytes());
    let refused = ComputePipeline::from_spirv(&ctx, "fill", &bad, &[]);
    let messages = ctx.take_validation_messages();
    assert!(!messages.is_empty(), "the validation layer reported nothing for an invalid module");
    // The layer refused the call rather than pass the module to the driver.
    let e = refused.err().expect("an invalid module makes no pipeline");
    assert!(e.to_string().contains("VALIDATION_FAILED"), "{e}");
}

/// CPU reference of glsl/gather.comp: thread i's sum of `rounds` dependent lookups.
fn gather_reference(table: &[[f32; 4]], threads: usize, rounds: u32) -> Vec<[f32; 4]> {
    let mask = table.len() as u32 - 1;
    (0..threads as u32)
        .map(|i| {
            let mut sum = [0f32; 4];
            let mut k = i.wrapping_mul(0x9E37_79B9);
            for _ in 0..rounds {
                k ^= k >> 16;
                k = k.wrapping_mul(0x85EB_CA6B);
                k ^= k >> 13;
                let v = table[(k & mask) as usize];
                for c in 0..4 {
                    sum[c] += v[c];
                }
                k = k.wrapping_add(v[0].to_bits());
            }
            sum
        })
        .collect()
}

#[test]
fn texel_buffer_reads_match_storage_buffer_reads_and_cpu() {
    with_gpu(|ctx| {
        // A table of exactly representable values, so every order of summation agrees.
        let table: Vec<[f32; 4]> = (0..4096u32).map(|i| [(i % 97) as f32, (i % 13) as f32 * 0.5, -(i as f32), 1.0]).collect();
        let (threads, rounds) = (1000usize, 64u32);
        let want = gather_reference(&table, threads, rounds);
        let t = Buffer::from_slice(ctx, "table", &table, MemoryKind::Device).unwrap();
        let push = vkinverse::kernels::GatherPush { threads: threads as u32, table_len: table.len() as u32, rounds };
        let mut profiler = Profiler::new(ctx, 8).unwrap();
        let mut outs = Vec::new();
        let mut cmd = CommandBuffer::new(ctx, "gather").unwrap();
        let kernels = [("gather", "Table"), ("gather_texel", "table_texels")];
        let mut groups = Vec::new();
        for (kernel, binding) in kernels {
            let p = ComputePipeline::new(ctx, kernel, &[]).unwrap();
            let out = Buffer::zeroed::<[f32; 4]>(ctx, "sums", threads, MemoryKind::Device).unwrap();
            let g = p.bind(&[(binding, &t), ("Sums", &out)]).unwrap();
            outs.push(out);
            groups.push((kernel, p, g));
        }
        cmd.record(|rec| {
            profiler.reset(rec);
            for (kernel, p, g) in &groups {
                profiler.begin(rec, kernel)?;
                rec.dispatch_linear(p, g, &push, threads as u64)?;
                profiler.end(rec)?;
            }
            Ok(())
        })
        .unwrap();
        cmd.submit_and_wait().unwrap();
        for (out, (kernel, _)) in outs.iter().zip(kernels) {
            let got: Vec<[f32; 4]> = out.read().unwrap();
            assert_eq!(got, want, "{kernel}");
        }
        for s in profiler.results().unwrap() {
            eprintln!("{}: {:.3} ms", s.name, s.ms);
        }

        // A buffer that is not a whole number of 16-byte texels cannot be viewed as one.
        let p = ComputePipeline::new(ctx, "gather_texel", &[]).unwrap();
        let odd = Buffer::zeroed::<f32>(ctx, "odd table", 5, MemoryKind::Device).unwrap();
        match p.bind(&[("table_texels", &odd), ("Sums", &outs[0])]) {
            Err(GpuError::BufferAccess { name, what }) => {
                assert_eq!(name, "odd table");
                assert!(what.contains("table_texels") && what.contains("20 bytes"), "{what}");
            }
            Err(e) => panic!("wrong error: {e}"),
            Ok(_) => panic!("a 20-byte texel buffer was accepted"),
        }
    });
}

/// A context whose device buffers are never mapped moves every write and read of them
/// through the two persistent staging buffers, in chunks: data arrive intact both ways
/// (through a kernel in between), the transfers are counted, and once the staging buffers
/// exist further transfers allocate nothing. Mapped host buffers stay mapped.
#[test]
fn unmappable_device_memory_goes_through_the_staging_buffers() {
    use vkinverse::gpu::STAGING_BYTES;
    let ctx = Context::new(&ContextOptions { validation: true, unmappable_device_memory: true, ..Default::default() }).unwrap();
    assert!(!ctx.device_memory_mappable());
    {
        let ops = BufferOps::new(&ctx).unwrap();
        // Two whole chunks and a part of a third.
        let n = (2 * STAGING_BYTES as usize + 12) / 4;
        let src = data(n, 5);
        let before = ctx.transfer_stats();
        let a = Buffer::from_slice(&ctx, "a", &src, MemoryKind::Device).unwrap();
        let b = Buffer::new(&ctx, "b", 4 * n as u64, MemoryKind::Device).unwrap();
        let mut cmd = CommandBuffer::new(&ctx, "t").unwrap();
        cmd.record(|rec| ops.copy(rec, &a, &b)).unwrap();
        cmd.submit_and_wait().unwrap();
        let got: Vec<f32> = b.read().unwrap();
        assert!(got == src, "the copy of the staged upload, read back through staging");
        let s = ctx.transfer_stats().since(&before);
        assert_eq!((s.staged_upload_bytes, s.staged_readback_bytes), (4 * n as u64, 4 * n as u64));
        assert_eq!((s.upload_bytes, s.readback_bytes), (4 * n as u64, 4 * n as u64));
        assert_eq!(s.staged_submissions, 6, "three chunks each way");
        assert_eq!(s.staging_allocations, 2, "one upload and one readback buffer, made on first use");

        // Steady state: small writes and reads of device buffers (an iteration's frame
        // counter, loss and θ) create no buffers; an Upload buffer is written mapped.
        let frame = Buffer::from_slice(&ctx, "frame", &[0u32], MemoryKind::Upload).unwrap();
        let before = ctx.transfer_stats();
        for i in 0..5u32 {
            frame.write(&[i]).unwrap();
            a.write(&[i as f32; 3]).unwrap();
            let back: Vec<f32> = a.read().unwrap();
            assert_eq!(back[..3], [i as f32; 3]);
            assert_eq!(back[3..], src[3..]);
        }
        let s = ctx.transfer_stats().since(&before);
        assert_eq!((s.buffers_created, s.staging_allocations), (0, 0), "{s:?}");
        assert_eq!(s.staged_upload_bytes, 5 * 12);
        assert_eq!(s.upload_bytes, 5 * (12 + 4), "the frame counter is counted too, mapped");
        assert_eq!(s.staged_readback_bytes, 5 * 4 * n as u64);
    }
    ctx.wait_idle().unwrap();
    let messages = ctx.take_validation_messages();
    assert!(messages.is_empty(), "validation messages:\n{}", messages.join("\n"));
    assert!(ctx.live_allocations().is_empty(), "{:?}", ctx.live_allocations());

    // The default context maps lavapipe's device memory: nothing staged.
    with_gpu(|ctx| {
        if std::env::var("VKINVERSE_UNMAPPABLE_DEVICE_MEMORY").is_ok_and(|v| v == "1") {
            assert!(!ctx.device_memory_mappable());
            return;
        }
        let before = ctx.transfer_stats();
        let a = Buffer::from_slice(ctx, "a", &[1.0f32; 64], MemoryKind::Device).unwrap();
        let _: Vec<f32> = a.read().unwrap();
        let s = ctx.transfer_stats().since(&before);
        assert_eq!((s.upload_bytes, s.readback_bytes), (256, 256));
        if ctx.info().device_type == "CPU" {
            assert_eq!((s.staged_upload_bytes, s.staged_readback_bytes, s.staging_allocations), (0, 0, 0), "{s:?}");
        }
    });
}

#[test]
fn contexts_are_made_and_dropped_from_many_threads_at_once() {
    // A library user may make contexts on several threads; some fail half-way (no such
    // device) while others are made, used and dropped. Every one must come out whole.
    let threads: Vec<_> = (0..8u32)
        .map(|t| {
            std::thread::spawn(move || {
                for round in 0..3u32 {
                    if (t + round) % 3 == 0 {
                        let options = ContextOptions { device: Some("no such device".into()), ..common::options() };
                        let e = Context::new(&options).err().expect("no device has that name");
                        assert!(matches!(e, GpuError::DeviceNotFound(_)), "{e}");
                        continue;
                    }
                    let sum = with_gpu(|ctx| {
                        let ops = BufferOps::new(ctx).unwrap();
                        let x = data(1000, t * 7 + round);
                        let a = Buffer::from_slice(ctx, "a", &x, MemoryKind::Device).unwrap();
                        let got = ops.sum(&a, false).unwrap();
                        let want: f64 = x.iter().map(|&v| v as f64).sum();
                        (got as f64, want)
                    });
                    assert!((sum.0 - sum.1).abs() < 1e-3, "thread {t} round {round}: {} against {}", sum.0, sum.1);
                }
            })
        })
        .collect();
    for t in threads {
        t.join().expect("a thread's contexts failed");
    }
}
