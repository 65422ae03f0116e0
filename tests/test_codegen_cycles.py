"""The Cortex-M4 cycle model (mpclab/codegen/cycles.py) and the step model built on it.

The table is checked on hand-written sequences whose cycles are counted by hand from the
TRM's timings, once on made-up addresses (no toolchain) and once assembled, run on QEMU and
traced. With the toolchain, the modelled cycles of real steps lie between the instruction
count and a stated bound, and ``sim=embedded_m4`` applies each call's modelled time.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_bicycle import controller, random_target
from test_codegen_pil import MARKERS

from conftest import compose_cfg
from mpclab.codegen import cycles, pil
from mpclab.codegen.step_model import fit
from mpclab.core.errors import ConfigError
from mpclab.runner.loop import simulate
from mpclab.runner.single_run import build_run

needs_toolchain = pytest.mark.needs("pil")

#: address -> (size, mnemonic, operands): a loop of 3 passes, loads and stores, the FPU
TABLE = {
    0x08000100: (2, "movs", "r0, #0"),
    0x08000102: (2, "movs", "r1, #3"),
    0x08000104: (2, "adds", "r0, #1"),
    0x08000106: (2, "cmp", "r0, r1"),
    0x08000108: (2, "bne.n", "8000104 <f+0x4>"),
    0x0800010a: (2, "ldr", "r2, [sp, #0]"),
    0x0800010c: (2, "ldr", "r3, [sp, #4]"),
    0x0800010e: (2, "str", "r2, [sp, #8]"),
    0x08000110: (4, "vdiv.f32", "s0, s0, s1"),
    0x08000114: (4, "vldr", "s2, [r4, #0]"),  # not the stack: flash (stream)
    0x08000118: (2, "ldr", "r5, [pc, #8]\t@ (8000124 <f+0x24>)"),  # a literal
    0x0800011a: (2, "push", "{r4, r5}"),
    0x0800011c: (2, "pop", "{r4, r5}"),
    0x0800011e: (4, "bl", "8000200 <g>"),
    0x08000200: (2, "bx", "lr"),
}
PCS = [0x08000100, 0x08000102, *[0x08000104, 0x08000106, 0x08000108] * 3,
       *range(0x0800010a, 0x08000118 + 1, 2)]


def _pcs() -> np.ndarray:
    out = [a for a in PCS if a in TABLE]
    return np.array(out + [0x0800011a, 0x0800011c], dtype=np.int64)


def test_normalize_strips_condition_flags_width_and_type() -> None:
    for raw, name in [("subscs.w", "sub"), ("vaddmi.f32", "vadd"), ("ldmia.w", "ldm"),
                      ("itte", "it"), ("bls.n", "b"), ("bl", "bl"), ("teq", "teq"),
                      ("movs", "mov"), ("vmovgt.f32", "vmov"), ("mls", "mls"),
                      ("negs", "neg"), ("bxne", "bx")]:
        assert cycles.normalize(raw) == name, raw


def test_the_table_gives_the_hand_counted_cycles() -> None:
    """movs, movs: 2; 3 passes of adds, cmp, bne (taken twice): 6 + 2 (1 + P) + 1; ldr
    after a branch 2, ldr and str pipelined 1 + 1; vdiv 14; vldr 2; a literal ldr 2 (after
    the vldr, no pipelining: vldr is the FPU's); push, pop of 2 registers 3 + 3 (the step
    ends at the pop; the bl follows it). Low (P = 1, no waits): 2 + 11 + 4 + 14 + 2 + 2 +
    6 = 41. High (P = 3, no pipelining, every jump and non-stack load waits 2 cycles): the
    two taken branches 2 (1 + 3) + 2 * 2 waits, ldr/ldr/str 2 + 2 + 2, the vldr and the
    literal + 2 + 2: 2 + (6 + 8 + 4 + 1) + 6 + 14 + 4 + 4 + 6 = 55."""
    program = cycles.Program(TABLE)
    pcs = _pcs()
    assert cycles.step_cycles(program, pcs, 0x0800011e, cycles.LOW) == 41
    assert cycles.step_cycles(program, pcs, 0x0800011e, cycles.HIGH) == 55
    # central: P = 2 (the targets are 16-bit), the jumps stay in the line (no wait), the
    # vldr streams 4 bytes (no line crossed), the literal misses the cold data cache: + 2
    central = cycles.step_cycles(program, pcs, 0x0800011e, cycles.CENTRAL)
    assert central == 41 + 2 + 2
    # warm: the literal's line is now in the data cache
    machine = cycles.Machine.cold()
    cycles.step_cycles(program, pcs, 0x0800011e, cycles.CENTRAL, machine)
    assert cycles.step_cycles(program, pcs, 0x0800011e, cycles.CENTRAL, machine) == 43


def test_an_instruction_without_timing_is_refused() -> None:
    program = cycles.Program({0x08000000: (4, "vsel", "s0, s1, s2")})  # not on the M4
    with pytest.raises(ValueError, match="no Cortex-M4 timing for 'vsel'"):
        cycles.step_cycles(program, np.array([0x08000000]), 0x08000004)


def test_the_fit_lies_on_or_above_every_point() -> None:
    its, cyc = [1, 1, 2, 3, 3], [100.0, 120.0, 150.0, 190.0, 170.0]
    base, slope, spread = fit(its, cyc)
    assert slope > 0 and spread >= 0
    assert all(base + slope * i >= c - 1e-9 for i, c in zip(its, cyc, strict=True))
    assert fit([0, 0], [5.0, 7.0])[:2] == (7.0, 0.0)


ASM = MARKERS + """\
int main(void)
{
    pil_begin();
    __asm__ volatile(
        "sub sp, #16\\n\\tmovs r0, #0\\n\\tmovs r1, #3\\n"
        "1:\\n\\tadds r0, r0, #1\\n\\tcmp r0, r1\\n\\tbne 1b\\n"
        "\\tldr r2, [sp]\\n\\tldr r3, [sp, #4]\\n\\tstr r2, [sp, #8]\\n\\tmul r2, r2, r3\\n"
        "\\tvadd.f32 s0, s0, s1\\n\\tvdiv.f32 s0, s0, s1\\n\\tvldr s2, [sp]\\n"
        "\\tpush {r4, r5}\\n\\tpop {r4, r5}\\n\\tadd sp, #16\\n\\tbl pil_end"
        ::: "r0", "r1", "r2", "r3", "r12", "lr", "s0", "s2", "cc", "memory");
    pil_puts("00 00 0000 0000000000000000\\ndone\\n");
    return 0;
}
"""


@needs_toolchain
def test_a_traced_sequence_on_qemu_gives_the_hand_counted_cycles(tmp_path) -> None:
    """Assembled, run and traced: sub, movs, movs 3; the loop 3 + 3 + 2 (1 + P) + 1; ldr 2,
    ldr 1, str 1 (pipelined); mul, vadd 2; vdiv 14; vldr 2; push, pop 3 + 3; add 1. Low
    (P = 1): 43; high (P = 3, no pipelining, the 2 taken branches wait 2 each; every load
    is from the stack): 43 + 4 + 4 + 2 = 53."""
    elf, _ = pil.cross_build(ASM, pil.Precision.single, tmp_path)
    (step,) = pil.run(elf, count_instructions=True, timings=cycles.BOUNDS)
    assert step.instructions + 1 == 3 + 9 + 10  # the window holds exactly the sequence
    assert step.cycles["low"] == 43
    assert step.cycles["high"] == 53
    assert 43 <= step.cycles["central"] <= 53


@needs_toolchain
@pytest.mark.parametrize("control_horizon", [1, 4])
def test_modelled_cycles_lie_between_the_instructions_and_a_bound(control_horizon,
                                                                  tmp_path) -> None:
    """Real steps in both precisions: instructions <= low <= central <= high <= 4 x
    instructions (the stated bound: no step averages 4 cycles per instruction even with
    every jump and every load from flash waiting)."""
    rng = np.random.default_rng(1)
    sil = controller(horizon=32, control_horizon=control_horizon, codegen=True)._sil
    x = np.array([[rng.normal(0, 3), rng.normal(0, 3), rng.uniform(-7, 7), 0.1, 0.01,
                   rng.uniform(0.3, 2.8)] for _ in range(4)])
    ref = np.stack([random_target(rng, xi, 32).ravel() for xi in x])
    for precision in pil.Precision:
        check = pil.pil_check(sil.library, x, ref, precision, tmp_path, timings=cycles.BOUNDS)
        for s in check.steps:
            c = s.cycles
            assert s.instructions <= c["low"] <= c["central"] <= c["high"] \
                <= 4 * s.instructions


@needs_toolchain
def test_sim_embedded_m4_applies_each_calls_modelled_time() -> None:
    """The turn with the generated C in single precision: every input acts after the step
    model's time at that call's iterations, recorded per step and summarised."""
    cfg = compose_cfg(["+experiment=bicycle_scheduled", "scenario=turn", "sim=embedded_m4",
                       "controller.codegen=true", "controller.codegen_precision=single",
                       "controller.control_horizon=4", "recorder=none", "progress=false",
                       "figures.enabled=false"])
    run = build_run(cfg)
    result = simulate(run)
    summary = result.summary | run.controller.metrics(result.steps)
    assert summary["status"] == "arrived" and summary["sim_latency"] == "modelled"
    calls = result.steps.iloc[:-1]
    model = run.controller._sil.step_model()
    expected = [model.seconds(int(i)) for i in calls["iterations"]]
    np.testing.assert_allclose(calls["latency_s"], expected, rtol=1e-12)
    np.testing.assert_allclose(calls["step_m4_s"].astype(float), expected, rtol=1e-12)
    assert summary["step_m4_max_ms"] == pytest.approx(1e3 * max(expected))
    assert summary["step_m4_p95_ms"] <= summary["step_m4_max_ms"]
    assert "single precision" in summary["step_m4_model"]
    assert 0 < summary["step_m4_max_ms"] < 20  # well inside the 20 ms sample


def test_sim_modelled_refuses_a_controller_without_a_board_model() -> None:
    cfg = compose_cfg(["+experiment=bicycle_scheduled", "scenario=turn", "sim=embedded_m4",
                       "recorder=none", "progress=false", "figures.enabled=false"])
    with pytest.raises(ConfigError, match="sim.latency=modelled.*controller.codegen=true"):
        simulate(build_run(cfg))
