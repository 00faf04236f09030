//! The loop nest of a Cranelift splitting step kernel, which both step kernels (the separable
//! one in [`super::step`] and the lattice's in [`super::lattice_steps`]) fill in:
//!
//! ```text
//! if no whole block of lanes or no step: return
//! run                                      (once per call)
//! for s in 0..n_steps
//!     for i in 0..n_kicks
//!         stage(drift[i], kick[i], reference position of (s, i))
//!         for each block of lanes: block(off)
//!     last(drift[n_kicks])
//!     for each block of lanes: last_block(off)
//! ```
//!
//! Stage-outer, block-inner: see [`crate::jit::step`] for why.

use cranelift_codegen::ir::condcodes::IntCC;
use cranelift_codegen::ir::types::{F64, I64};
use cranelift_codegen::ir::{BlockArg, InstBuilder, Value};
use cranelift_frontend::FunctionBuilder;

use super::flags;

/// The kernel arguments the loops read (values of the entry block).
pub(super) struct LoopArgs {
    pub lanes: Value,
    pub n_steps: Value,
    /// `n_kicks + 1` drift coefficients.
    pub drift: Value,
    /// `n_kicks` kick coefficients.
    pub kick: Value,
    pub n_kicks: Value,
    /// The tangent kernels' reference positions, `N` values per stage of every step.
    pub stages: Option<Value>,
    /// The lattice's `N`.
    pub n: usize,
    /// Lanes per block: the lanes beyond the last whole block are not touched.
    pub block_lanes: i64,
}

impl LoopArgs {
    /// Reads the kernel's parameters from the entry block (the builder in it): the loops'
    /// arguments and the kernel's own `x`, `stride`, `w` (inverse masses) and `scratch`.
    pub fn read(
        b: &mut FunctionBuilder,
        tangent: bool,
        n: usize,
        block_lanes: i64,
    ) -> (Self, [Value; 4]) {
        let entry = b.current_block().expect("the entry block");
        let params = b.block_params(entry).to_vec();
        let (stages, rest) = if tangent {
            (Some(params[0]), &params[1..])
        } else {
            (None, &params[..])
        };
        let args = LoopArgs {
            lanes: rest[2],
            n_steps: rest[3],
            drift: rest[4],
            kick: rest[5],
            n_kicks: rest[6],
            stages,
            n,
            block_lanes,
        };
        (args, [rest[0], rest[1], rest[7], rest[8]])
    }
}

/// What a kernel emits inside the loops; each method is called once, with the builder in the
/// block it names.
pub(super) trait StepBody {
    /// Before the first step.
    fn run(&mut self, b: &mut FunctionBuilder);
    /// Before a stage's blocks: its drift and kick coefficients and, for a tangent kernel, the
    /// address of the reference position before its kick.
    fn stage(&mut self, b: &mut FunctionBuilder, ch: Value, dh: Value, reference: Option<Value>);
    /// A stage's work on one block of lanes, `off` the byte offset of the block's first lane.
    fn block(&mut self, b: &mut FunctionBuilder, off: Value);
    /// Before the last drift's blocks, with its coefficient.
    fn last(&mut self, b: &mut FunctionBuilder, ch: Value);
    /// The last drift of one block of lanes.
    fn last_block(&mut self, b: &mut FunctionBuilder, off: Value);
}

/// Emits the loop nest from the entry block (its parameters already read) to the return, and
/// seals the blocks.
pub(super) fn step_loops(b: &mut FunctionBuilder, args: &LoopArgs, body: &mut impl StepBody) {
    let run = b.create_block();
    let step_head = b.create_block();
    let stage_head = b.create_block();
    let stage_body = b.create_block();
    let blk = b.create_block();
    let stage_next = b.create_block();
    let last = b.create_block();
    let last_blk = b.create_block();
    let step_next = b.create_block();
    let exit = b.create_block();
    let s = b.append_block_param(step_head, I64);
    let i = b.append_block_param(stage_head, I64);
    let off = b.append_block_param(blk, I64);
    let last_off = b.append_block_param(last_blk, I64);

    let whole = b.ins().band_imm_s(args.lanes, !(args.block_lanes - 1));
    let end = b.ins().ishl_imm_u(whole, 3);
    let no_lanes = b.ins().icmp_imm_u(IntCC::Equal, end, 0);
    let no_steps = b.ins().icmp_imm_u(IntCC::Equal, args.n_steps, 0);
    let nothing = b.ins().bor(no_lanes, no_steps);
    b.ins().brif(nothing, exit, &[], run, &[]);

    b.switch_to_block(run);
    body.run(b);
    let zero = b.ins().iconst(I64, 0);
    b.ins().jump(step_head, &[BlockArg::Value(zero)]);

    // step_head(s): the stage loop from its first stage.
    b.switch_to_block(step_head);
    b.ins().jump(stage_head, &[BlockArg::Value(zero)]);

    // stage_head(i): i < n_kicks -> stage i; else the last drift.
    b.switch_to_block(stage_head);
    let more = b.ins().icmp(IntCC::UnsignedLessThan, i, args.n_kicks);
    b.ins().brif(more, stage_body, &[], last, &[]);

    b.switch_to_block(stage_body);
    let ioff = b.ins().ishl_imm_u(i, 3);
    let dp = b.ins().iadd(args.drift, ioff);
    let ch = b.ins().load(F64, flags(), dp, 0);
    let kp = b.ins().iadd(args.kick, ioff);
    let dh = b.ins().load(F64, flags(), kp, 0);
    let reference = args.stages.map(|st| {
        // stages + (s * n_kicks + i) * N * 8
        let si = b.ins().imul(s, args.n_kicks);
        let si = b.ins().iadd(si, i);
        let byte = b.ins().imul_imm_s(si, (args.n * 8) as i64);
        b.ins().iadd(st, byte)
    });
    body.stage(b, ch, dh, reference);
    b.ins().jump(blk, &[BlockArg::Value(zero)]);

    // blk(off): one block of lanes.
    b.switch_to_block(blk);
    body.block(b, off);
    let next = b.ins().iadd_imm_s(off, 8 * args.block_lanes);
    let more = b.ins().icmp(IntCC::UnsignedLessThan, next, end);
    b.ins()
        .brif(more, blk, &[BlockArg::Value(next)], stage_next, &[]);

    b.switch_to_block(stage_next);
    let i1 = b.ins().iadd_imm_s(i, 1);
    b.ins().jump(stage_head, &[BlockArg::Value(i1)]);

    // last: the drift after the last kick, over every block.
    b.switch_to_block(last);
    let loff = b.ins().ishl_imm_u(args.n_kicks, 3);
    let lp = b.ins().iadd(args.drift, loff);
    let ch_last = b.ins().load(F64, flags(), lp, 0);
    body.last(b, ch_last);
    b.ins().jump(last_blk, &[BlockArg::Value(zero)]);

    b.switch_to_block(last_blk);
    body.last_block(b, last_off);
    let next = b.ins().iadd_imm_s(last_off, 8 * args.block_lanes);
    let more = b.ins().icmp(IntCC::UnsignedLessThan, next, end);
    b.ins()
        .brif(more, last_blk, &[BlockArg::Value(next)], step_next, &[]);

    b.switch_to_block(step_next);
    let s1 = b.ins().iadd_imm_s(s, 1);
    let more = b.ins().icmp(IntCC::UnsignedLessThan, s1, args.n_steps);
    b.ins()
        .brif(more, step_head, &[BlockArg::Value(s1)], exit, &[]);

    b.switch_to_block(exit);
    b.ins().return_(&[]);
    b.seal_all_blocks();
}
