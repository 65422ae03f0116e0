"""Cycles of a PIL instruction trace on a Cortex-M4F with the STM32F401's flash: a cycle model.

QEMU executes the firmware without timing; its ``-singlestep -d exec,nochain`` log gives the
address of every executed instruction (:mod:`mpclab.codegen.pil`). Each address is mapped to
its instruction by ``arm-none-eabi-objdump -d`` of the same ELF, and each executed instruction
is weighted by the Cortex-M4 Technical Reference Manual's timings (ARM DDI 0439B: core
instructions ch. 3, table 3-1; FPU ch. 7, table 7-1), plus flash wait states (ST RM0368: the
F401's flash needs 2 wait states at 84 MHz, partly hidden by the ART accelerator's prefetch
and caches):

* data processing, compare, shift, bit field, extend, IT, NOP: 1; MUL, UMULL, SMULL, UMLAL,
  SMLAL: 1; MLA, MLS: 2; UDIV, SDIV: 2 to 12 (early termination on the operands' sizes,
  which the trace does not carry: ``div`` cycles);
* a single load or store (LDR, LDRB, LDRH, LDRSB, LDRSH, STR, STRB, STRH): 2, or 1 when it
  follows another load or store single (``pipelined``: their address and data phases
  overlap; not after a store with a register offset); LDRD, STRD: 3; LDM, STM, PUSH, POP:
  1 + N (N registers);
* branches (B, BL, BX, BLX, CBZ, CBNZ; POP/LDM/LDR/MOV/ADD that write PC): 1 not taken,
  1 + P taken (P, the pipeline refill, 1 to 3: ``refill``; with ``refill_by_target`` one
  more when the target is a 32-bit instruction on a half-word boundary); TBB, TBH: 2 + P;
  taken is read from the trace (the next executed address is not the next instruction's);
* FPU: VADD, VSUB, VMUL, VNMUL, VABS, VNEG, VCMP(E), VCVT, VMOV, VMRS, VMSR: 1, VMOV of two
  core registers: 2; VMLA, VMLS, VNMLA, VNMLS, VFMA, VFMS, VFNMA, VFNMS: 3; VDIV, VSQRT: 14;
  VLDR, VSTR: 2 (3 for a double register); VLDM, VSTM, VPUSH, VPOP: 1 + N (N words);
* flash wait states on instruction fetch (``fetch``): ``hit`` none; ``art`` the ART accelerator
  as RM0368 describes it: sequential code is prefetched (no wait), a jump to the current or
  the prefetched 128-bit line is free, else the instruction cache (64 lines of 128 bits,
  modelled fully associative, least recently used; a line enters it when it missed) hits or
  the jump pays the wait states; warm from the previous step; ``miss``: every taken branch
  pays them;
* flash wait states on data (``data``; loads from the stack are SRAM, no wait): ``hit`` none;
  ``stream``: PC-relative literal loads go through the ART's data cache (8 lines of 128
  bits, modelled as above), every other load as a sequential read of flash (the constant
  tables): the wait states once per 16 bytes read (an overestimate for the state and
  reference, which a board keeps in SRAM); ``miss``: every load that is not from the stack
  pays them.

Not modelled: IT folding onto the preceding instruction, stalls of the FPU's register
dependencies, bus contention between instruction and data fetch (``LDR [PC]``), the
write buffer, interrupts. :data:`LOW`, :data:`CENTRAL` and :data:`HIGH` bracket the model;
:func:`step_cycles` weighs one step's executed addresses.
"""

from __future__ import annotations

import re
import subprocess
from collections import OrderedDict
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import numpy as np
import numpy.typing as npt

UIntArray = npt.NDArray[np.int64]

COND = frozenset("eq ne cs hs cc lo mi pl vs vc hi ls ge lt gt le al".split())
#: 1 cycle: data processing, compare, bit field, extend, hints, single-cycle multiplies,
#: and the FPU's single-cycle operations
ONE = frozenset("""
    mov mvn movw movt neg add adc sub sbc rsb and orr eor bic orn cmp cmn tst teq lsl lsr asr ror
    rrx clz rbit rev rev16 revsh sxtb sxth uxtb uxth sxtab sxtah uxtab uxtah ubfx sbfx bfi bfc
    addw subw adr nop ssat usat sel mul umull smull umlal smlal smulbb smulbt smultb smultt
    smulwb smulwt smlabb smlabt smlatb smlatt smlawb smlawt smmul smmla smmls smlad smlsd smuad
    smusd usad8 usada8 pkhbt pkhtb qadd qsub qdadd qdsub uadd8 usub8 sadd8 ssub8 cpsid cpsie
    mrs msr
    vadd vsub vmul vnmul vabs vneg vcmp vcmpe vcvt vcvtr vcvtb vcvtt vmrs vmsr
""".split())
MAC = frozenset("vmla vmls vnmla vnmls vfma vfms vfnma vfnms".split())  # 3
LOAD1 = {"ldr": 4, "ldrb": 1, "ldrh": 2, "ldrsb": 1, "ldrsh": 2, "ldrex": 4, "ldrexb": 1,
         "ldrexh": 2, "ldrt": 4}
STORE1 = frozenset("str strb strh strex strexb strexh strt".split())
BRANCH = frozenset("b bl bx blx cbz cbnz".split())
KNOWN = (ONE | MAC | set(LOAD1) | STORE1 | BRANCH
         | {"mla", "mls", "udiv", "sdiv", "ldrd", "strd", "tbb", "tbh", "push", "pop", "vpush",
            "vpop", "vldr", "vstr", "vmov", "vdiv", "vsqrt", "dsb", "dmb", "isb", "it", "ldm",
            "stm", "vldm", "vstm", "bkpt", "svc", "wfi", "wfe", "sev", "yield"})


class Fetch(StrEnum):
    hit = "hit"
    art = "art"
    miss = "miss"


class Data(StrEnum):
    hit = "hit"
    stream = "stream"
    miss = "miss"


@dataclass(frozen=True)
class Timing:
    """The model's free parameters (see the module docstring)."""

    refill: int = 2  # P, cycles to refill the pipeline after a taken branch (1-3)
    refill_by_target: bool = True  # +1 for a 32-bit target on a half-word boundary (<= 3)
    pipelined: bool = True  # neighbouring loads/stores single overlap
    wait_states: int = 2  # flash at 84 MHz, 2.7-3.6 V (RM0368)
    fetch: Fetch = Fetch.art
    data: Data = Data.stream
    div: int = 7  # UDIV/SDIV: 2-12 by the operands


#: the lower bound: 1-cycle refills, every flash access hidden
LOW = Timing(refill=1, refill_by_target=False, fetch=Fetch.hit, data=Data.hit, div=2)
#: the central estimate
CENTRAL = Timing()
#: the upper bound: 3-cycle refills, no load pipelining, every jump and non-stack load waits
HIGH = Timing(refill=3, refill_by_target=False, pipelined=False, fetch=Fetch.miss,
              data=Data.miss, div=12)
BOUNDS = {"low": LOW, "central": CENTRAL, "high": HIGH}

FLASH = (0x08000000, 0x08100000)
LINE = 16  # bytes of a flash line (128 bits)
ICACHE_LINES, DCACHE_LINES = 64, 8


@dataclass(frozen=True)
class Instruction:
    """One instruction of the ELF, as the model sees it."""

    address: int
    size: int
    mnemonic: str  # normalized: no condition, flag-setting 's', width or data type suffix
    operands: str
    base: int  # cycles without refill, pipelining and wait states (UDIV/SDIV: 0, see div)
    branch: bool  # may write PC
    single: bool  # a load or store single (pipelines after another)
    breaks_pipeline: bool  # a store with a register offset: nothing pipelines after it
    data_bytes: int  # bytes it loads (0: none)
    stack: bool  # loads from the stack (SRAM)
    literal: int | None  # the literal's address of a PC-relative load


def normalize(mnemonic: str) -> str:
    """The instruction's name without width/data-type suffix, condition or flag-setting 's'
    (``subscs.w`` -> ``sub``, ``vaddmi.f32`` -> ``vadd``, ``ldmia.w`` -> ``ldm``, ``itte`` ->
    ``it``); unknown names come back as they are."""
    m = mnemonic.split(".")[0].lower()
    for prefix in ("vldm", "vstm", "ldm", "stm"):
        if m.startswith(prefix) and m not in KNOWN:
            return prefix
    if re.fullmatch(r"it[te]{0,3}", m):
        return "it"
    bare = m[:-2] if m[-2:] in COND else None  # without a condition (bls: b + ls)
    for cut in (m, bare, m[:-1] if m.endswith("s") else None,
                bare[:-1] if bare and bare.endswith("s") else None):
        if cut and cut in KNOWN and not (cut in BRANCH and cut != m and cut != bare):
            return cut
    return m


def _registers(operands: str) -> list[str]:
    """The registers of a ``{...}`` list (ranges ``r4-r7`` and ``d8-d9`` expanded)."""
    inner = operands[operands.find("{") + 1: operands.find("}")]
    out = []
    for part in (p.strip() for p in inner.split(",") if p.strip()):
        if "-" in part:
            a, b = part.split("-")
            out += [f"{a[0]}{i}" for i in range(int(a[1:]), int(b[1:]) + 1)]
        else:
            out.append(part)
    return out


def _words(regs: list[str]) -> int:
    """Words moved for a register list (a double register is 2)."""
    return sum(2 if r.startswith("d") else 1 for r in regs)


def classify(address: int, size: int, mnemonic: str, operands: str) -> Instruction:
    """The model's view of one disassembled instruction; ``ValueError`` for a name the table
    does not hold."""
    m = normalize(mnemonic)
    if m not in KNOWN:
        raise ValueError(f"no Cortex-M4 timing for {mnemonic!r} at {address:#x}")
    ops = operands.split("\t")[0].split("@")[0].replace(" ", "")
    first = ops.split(",")[0]
    branch = m in BRANCH or m in ("tbb", "tbh") or (m in ("mov", "add", "ldr") and first == "pc")
    single = m in LOAD1 or m in STORE1
    regs = _registers(operands) if "{" in operands else []
    writes_pc = "pc" in regs
    data_bytes, base = 0, 1
    if m in ("mla", "mls"):
        base = 2
    elif m in ("udiv", "sdiv"):
        base = 0
    elif m in MAC:
        base = 3
    elif m in ("vdiv", "vsqrt"):
        base = 14
    elif m in LOAD1 or m in STORE1:
        base, data_bytes = 2, LOAD1.get(m, 0)
    elif m in ("ldrd", "strd"):
        base, data_bytes = 3, 8 if m == "ldrd" else 0
    elif m in ("tbb", "tbh"):
        base, data_bytes = 2, 1 if m == "tbb" else 2
    elif m in ("ldm", "stm", "push", "pop"):
        base = 1 + len(regs)
        data_bytes = 4 * len(regs) if m in ("ldm", "pop") else 0
        branch = branch or writes_pc
    elif m in ("vldm", "vstm", "vpush", "vpop"):
        base = 1 + _words(regs)
        data_bytes = 4 * _words(regs) if m in ("vldm", "vpop") else 0
    elif m in ("vldr", "vstr"):
        base = 3 if first.startswith("d") else 2
        data_bytes = (8 if first.startswith("d") else 4) if m == "vldr" else 0
    elif m == "vmov":
        base = 2 if sum(1 for r in ops.split(",") if re.fullmatch(r"r\d+|ip|lr", r)) >= 2 else 1
    elif m in ("dsb", "dmb", "isb"):
        base = 2  # 1 + B (B: the barrier's wait, 1 assumed)
    if m in ("pop", "vpop"):
        stack = True
    else:
        stack = "[sp" in ops
    lit = re.search(r"\[pc[,\]].*?@\s*\(?([0-9a-f]+)", operands)
    literal = int(lit.group(1), 16) if lit and data_bytes else None
    breaks = m in STORE1 and re.search(r"\[\w+,\w+", ops) is not None
    return Instruction(address, size, m, operands, base, branch, single, breaks, data_bytes,
                       stack, literal)


_LINE = re.compile(r"^\s*([0-9a-f]+):\t([0-9a-f ]+?)\s*\t(\S+)\s*(.*)$")


def disassemble(elf: Path) -> dict[int, tuple[int, str, str]]:
    """``{address: (size, mnemonic, operands)}`` of every instruction of ``elf``'s code."""
    out = subprocess.run(["arm-none-eabi-objdump", "-d", str(elf)], check=True,
                         capture_output=True, text=True).stdout
    table = {}
    for line in out.splitlines():
        hit = _LINE.match(line)
        if hit is None or hit.group(3).startswith("."):  # .word, .short: data in the code
            continue
        raw = hit.group(2).split()
        table[int(hit.group(1), 16)] = (2 * len(raw) if all(len(w) == 4 for w in raw)
                                         else len("".join(raw)) // 2, hit.group(3),
                                         hit.group(4).strip())
    return table


class Program:
    """The instructions of one firmware as arrays over their sorted addresses; an
    instruction the table has no timing for is refused when a step executes it."""

    def __init__(self, table: dict[int, tuple[int, str, str]]) -> None:
        self.address = np.array(sorted(table), dtype=np.int64)
        insns: list[Instruction | None] = []
        self._unknown: dict[int, str] = {}
        for a in self.address.tolist():
            try:
                insns.append(classify(a, *table[a]))
            except ValueError as exc:
                insns.append(None)
                self._unknown[a] = str(exc)

        def column(get, dtype):  # noqa: ANN001 (a field of every instruction)
            return np.array([0 if i is None else get(i) for i in insns], dtype=dtype)

        self.size = column(lambda i: i.size, np.int64)
        self.base = column(lambda i: i.base, float)
        self.div = column(lambda i: i.mnemonic in ("udiv", "sdiv"), bool)
        self.branch = column(lambda i: i.branch, bool)
        self.single = column(lambda i: i.single, bool)
        self.pipelines_next = column(lambda i: i.single and not i.breaks_pipeline, bool)
        self.loads = column(lambda i: i.data_bytes if not i.stack else 0, np.int64)
        self.literal = column(lambda i: -1 if i.literal is None else i.literal, np.int64)
        self.mnemonic = [None if i is None else i.mnemonic for i in insns]

    @classmethod
    def of(cls, elf: Path) -> Program:
        return cls(disassemble(elf))

    def index(self, pcs: UIntArray) -> UIntArray:
        """Positions of the executed addresses ``pcs`` in the arrays."""
        idx = np.searchsorted(self.address, pcs)
        bad = (idx >= self.address.size) | (self.address[np.minimum(idx, self.address.size - 1)]
                                             != pcs)
        if bad.any():
            raise ValueError(f"executed address {int(pcs[bad][0]):#x} is no instruction of "
                             "the ELF")
        for a in set(pcs[np.isin(pcs, list(self._unknown))].tolist()) if self._unknown else ():
            raise ValueError(self._unknown[a])
        return idx


@dataclass
class _Cache:
    """A fully associative, least-recently-used cache of flash lines."""

    lines: int
    held: OrderedDict[int, None]

    def access(self, line: int) -> bool:
        """Whether ``line`` hits; a miss brings it in."""
        if line in self.held:
            self.held.move_to_end(line)
            return True
        self.held[line] = None
        if len(self.held) > self.lines:
            self.held.popitem(last=False)
        return False


@dataclass
class Machine:
    """What carries over from one step to the next: the ART's caches (warm)."""

    icache: _Cache
    dcache: _Cache

    @classmethod
    def cold(cls) -> Machine:
        return cls(_Cache(ICACHE_LINES, OrderedDict()), _Cache(DCACHE_LINES, OrderedDict()))


def step_cycles(program: Program, pcs: UIntArray, next_pc: int, timing: Timing = CENTRAL,
                machine: Machine | None = None) -> float:
    """Modelled cycles of the executed addresses ``pcs`` (in order), ``next_pc`` the one
    executed after the last; ``machine`` carries the caches from step to step."""
    machine = machine or Machine.cold()
    pcs = np.asarray(pcs, dtype=np.int64)
    if not pcs.size:
        return 0.0
    p = program
    idx = p.index(pcs)
    nxt = np.append(pcs[1:], int(next_pc))
    taken = nxt != pcs + p.size[idx]
    odd = taken & ~p.branch[idx]
    if odd.any():
        k = int(np.flatnonzero(odd)[0])
        raise ValueError(f"{p.mnemonic[idx[k]]} at {int(pcs[k]):#x} is followed by "
                         f"{int(nxt[k]):#x}: not a branch (an exception in the step?)")
    c = p.base[idx].copy()
    c[p.div[idx]] = timing.div
    if timing.pipelined:  # a load/store single right after one that lets it overlap
        c[1:] -= p.single[idx[1:]] & p.pipelines_next[idx[:-1]] & ~taken[:-1]
    c += timing.refill * taken
    if timing.refill_by_target and timing.refill < 3:
        targets = nxt[taken]
        c[taken] += (p.size[p.index(targets)] == 4) & (targets % 4 == 2)
    ws = timing.wait_states
    line = pcs // LINE
    arrived = np.zeros(pcs.size, dtype=bool)  # fetched after a taken branch, from flash
    arrived[1:] = taken[:-1] & (pcs[1:] >= FLASH[0]) & (pcs[1:] < FLASH[1])
    if timing.fetch is Fetch.miss:
        c += ws * arrived
    elif timing.fetch is Fetch.art:  # not the current or the prefetched line: the cache
        far = np.flatnonzero(arrived[1:] & (line[1:] != line[:-1])
                             & (line[1:] != line[:-1] + 1)) + 1
        for k, ln in zip(far.tolist(), line[far].tolist(), strict=True):
            if not machine.icache.access(ln):
                c[k] += ws
    loads = p.loads[idx]
    if timing.data is Data.miss:
        c += ws * (loads > 0)
    elif timing.data is Data.stream:
        literal = p.literal[idx]
        for k in np.flatnonzero((loads > 0) & (literal >= 0)).tolist():
            if not machine.dcache.access(int(literal[k]) // LINE):
                c[k] += ws
        streamed = np.where(literal < 0, loads, 0)
        after = np.cumsum(streamed)
        c += ws * (after // LINE - (after - streamed) // LINE)
    return float(c.sum())
