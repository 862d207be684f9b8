"""The C header on the microcontrollers it is written for: cross-compiled and emulated.

:func:`cross_compile` builds a header with Debian's ``arm-none-eabi-gcc`` for one of
:data:`TARGETS` — Cortex-M0+ (no FPU), Cortex-M4F (single-precision FPU) and Cortex-M7
(double-precision FPU) — under the strict flags :data:`STRICT_FLAGS` (``-Werror``), with
both ``<prefix>_compensate`` and ``<prefix>_step`` instantiated; it returns the object's
undefined symbols (a soft-double routine such as ``__aeabi_dadd`` is a call the FPU cannot
do: :func:`soft_double_symbols`) and its code and constant bytes.  :func:`host_compile`
builds the same under the same flags on the host (x86-64, LP64), and :func:`link_bare` links a
target's object with ``-nostdlib`` and libm (and libgcc) only.

:class:`Emulator` links that object into a bare image (no start-up code, libgcc and newlib
for whatever the build calls) and runs it under the ``unicorn`` CPU emulator as a
Cortex-M4 with its FPU: ``evaluate`` calls ``<prefix>_compensate`` on one point,
``step`` calls ``<prefix>_step`` on the emulated state; both return what the part computes,
and with ``count=True`` how many Thumb instructions ran, split by the function they ran in
(the header's own code, soft-double routines, libm).  ``experiments/bench_mcu.py`` reports
those counts; ``tests/test_mcu.py`` checks the builds and the emulated outputs against torch.

Needs the toolchain (``make arm-toolchain`` installs Debian's ``gcc-arm-none-eabi`` and
``libnewlib-arm-none-eabi``) and, for the emulator, the ``unicorn`` package (test extra).
"""

from __future__ import annotations

import bisect
import re
import shutil
import struct
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ExportError

__all__ = ["TARGETS", "STRICT_FLAGS", "CrossBuild", "Emulator", "cross_compile",
           "host_compile", "link_bare", "soft_double_symbols", "toolchain", "FLOAT_TARGETS"]

#: The Cortex-M cores the header is built for: compiler flags per target.
TARGETS: dict[str, tuple[str, ...]] = {
    "cortex-m0plus": ("-mcpu=cortex-m0plus", "-mthumb", "-mfloat-abi=soft"),
    "cortex-m4f": ("-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard"),
    "cortex-m7": ("-mcpu=cortex-m7", "-mthumb", "-mfpu=fpv5-d16", "-mfloat-abi=hard"),
}
#: Targets without double-precision hardware: the header must take its float path there.
FLOAT_TARGETS = ("cortex-m0plus", "cortex-m4f")
#: Every header builds without a warning under these.
STRICT_FLAGS = ("-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Wshadow", "-Wdouble-promotion",
                "-Wconversion", "-Wsign-conversion", "-Werror")
#: Run-time routines of double arithmetic in software (Arm EABI and libgcc names).
_SOFT_DOUBLE = re.compile(r"^(__aeabi_(d[a-z0-9]+|[a-z0-9]+2d|[a-z0-9]+2dz?)|"
                          r"__(add|sub|mul|div|neg|extendsf|truncdfsf|fix|fixuns|float|"
                          r"floatun|eq|ne|lt|le|gt|ge|unord|cmp)[a-z]*df[0-9a-z]*)$")
#: libm's exponentials (the float path must not call them)
_LIBM = re.compile(r"^(__ieee754_)?(exp|expm1|__expf|__math)[a-z0-9_]*$")

_WRAPPER = r"""
#include "model.h"
/* The entry points the emulator calls: compensate with its own arguments (r0-r3), step
 * on globals the host writes (its state is kept here between calls). */
int mcu_eval(const float *s, const thermonet_real_t *raw, thermonet_real_t *comp,
             thermonet_real_t *drift);
int mcu_eval(const float *s, const thermonet_real_t *raw, thermonet_real_t *comp,
             thermonet_real_t *drift)
{
    return PFX_EVAL;
}
PFX_state mcu_state;
thermonet_time_t mcu_time;
float mcu_temp;
float mcu_prox[PFX_N_PROXIES > 0 ? PFX_N_PROXIES : 1];
thermonet_real_t mcu_raw[PFX_N_AXES], mcu_comp[PFX_N_AXES], mcu_drift[PFX_N_AXES];
int mcu_flag, mcu_ret;
void mcu_init(void);
void mcu_init(void)
{
    PFX_init(&mcu_state);
}
void mcu_step(void);
void mcu_step(void)
{
    mcu_ret = PFX_step(&mcu_state, mcu_time, mcu_temp, PROXY_ARG mcu_raw, mcu_comp,
                       mcu_drift, &mcu_flag);
}
"""

_LINK_SCRIPT = """
ENTRY(mcu_eval)
SECTIONS {
  . = 0x10000;
  .text : { *(.text*) *(.rodata*) *(.ARM.extab*) }
  .ARM.exidx : { *(.ARM.exidx*) }
  .data : { *(.data*) }
  .bss : { *(.bss*) *(COMMON) }
  _end = .;
  end = .;
}
"""


def toolchain() -> dict[str, str]:
    """Paths of arm-none-eabi ``gcc``, ``nm``, ``objcopy`` and ``size``.

    Raises
    ------
    ExportError
        The toolchain is not installed (``make arm-toolchain`` installs it).
    """
    tools = {t: shutil.which(f"arm-none-eabi-{t}") for t in ("gcc", "nm", "objcopy", "size")}
    missing = [f"arm-none-eabi-{t}" for t, p in tools.items() if p is None]
    if missing:
        raise ExportError(f"{', '.join(missing)} not found: run `make arm-toolchain` (Debian "
                          "packages gcc-arm-none-eabi and libnewlib-arm-none-eabi)")
    return {t: str(p) for t, p in tools.items()}


def soft_double_symbols(symbols: list[str] | set[str]) -> list[str]:
    """The names among ``symbols`` that are software double-precision routines."""
    return sorted(s for s in symbols if _SOFT_DOUBLE.match(s))


@dataclass
class CrossBuild:
    """One header built for one target.

    Attributes
    ----------
    target : str
    obj : Path
        The object file (``model.h`` + the emulator's entry points, ``-ffunction-sections``).
    undefined : list of str
        Symbols it calls outside itself (run-time and libm routines).
    code_bytes, const_bytes : int
        ``.text`` (instructions and their literal pools) and ``.rodata`` (the constant
        arrays) of the object.
    flags : tuple of str
    """

    target: str
    obj: Path
    undefined: list[str]
    code_bytes: int
    const_bytes: int
    flags: tuple[str, ...] = field(default_factory=tuple)

    @property
    def soft_double(self) -> list[str]:
        return soft_double_symbols(self.undefined)

    @property
    def libm(self) -> list[str]:
        return sorted(s for s in self.undefined if _LIBM.match(s))


def _run(cmd: list[str], what: str) -> str:
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise ExportError(f"{what} failed: {done.stderr.strip() or done.stdout.strip()}")
    return done.stdout


def cross_compile(header_text: str, target: str, out_dir: str | Path, *,
                  prefix: str = "thermonet", has_proxies: bool = False,
                  opt: str = "-O2", extra: tuple[str, ...] = (),
                  recurrent: bool = False) -> CrossBuild:
    """Build ``header_text`` with its compensate and step for ``target`` (:data:`TARGETS`)
    under :data:`STRICT_FLAGS` into ``out_dir``.

    ``has_proxies``: ``<prefix>_step`` takes a proxies argument
    (:func:`.c_stream_render.stream_signature_has_proxies`).  ``extra``: more flags (e.g.
    ``-DTHERMONET_USE_DOUBLE`` to build the double path on a float target).  ``recurrent``:
    the header is a recurrent model's (``<prefix>_compensate_state``, :mod:`.c_recurrent`).

    Raises
    ------
    ExportError
        No toolchain, or the build fails (a warning is an error).
    """
    tools = toolchain()
    out = Path(out_dir)
    _write_wrapper(header_text, out, prefix, has_proxies, recurrent)
    flags = (*TARGETS[target], *STRICT_FLAGS, opt, "-ffunction-sections", "-fdata-sections",
             *extra)
    obj = out / "mcu.o"
    _run([tools["gcc"], *flags, "-c", str(out / "mcu.c"), "-o", str(obj)],
         f"arm-none-eabi-gcc {target}")
    undefined = [ln.split()[-1] for ln in _run([tools["nm"], "-u", str(obj)], "nm").splitlines()
                 if ln.strip()]
    code = const = 0
    for ln in _run([tools["size"], "-A", str(obj)], "size").splitlines():
        parts = ln.split()
        if len(parts) >= 2 and parts[1].isdigit():
            if parts[0].startswith(".text"):
                code += int(parts[1])
            elif parts[0].startswith(".rodata"):
                const += int(parts[1])
    return CrossBuild(target, obj, undefined, code, const, tuple(flags))


def host_compile(header_text: str, out_dir: str | Path, *, prefix: str = "thermonet",
                 has_proxies: bool = False, recurrent: bool = False,
                 extra: tuple[str, ...] = ()) -> Path:
    """Build the same wrapper as :func:`cross_compile` (compensate and step instantiated) with
    the host's ``gcc`` (x86-64: LP64, where ``long`` is 64 bits) under :data:`STRICT_FLAGS`;
    returns the object file.  ``extra``: ``-DTHERMONET_USE_FLOAT`` / ``_DOUBLE`` for a path.

    Raises
    ------
    ExportError
        The build fails (a warning is an error).
    """
    out = Path(out_dir)
    _write_wrapper(header_text, out, prefix, has_proxies, recurrent)
    obj = out / "host.o"
    _run(["gcc", *STRICT_FLAGS, "-O2", *extra, "-c", str(out / "mcu.c"), "-o", str(obj)],
         "gcc (host)")
    return obj


def link_bare(build: CrossBuild, out: str | Path) -> list[str]:
    """Link ``build``'s object alone for its target with ``-nostdlib`` and only libm and the
    compiler's run-time library (libgcc: the soft-float routines of an FPU-less core) —
    no libc, no start-up code (entry: the wrapper's ``mcu_eval``, unused sections dropped).
    Returns the symbols left undefined ([] where it links)."""
    tools = toolchain()
    done = subprocess.run([tools["gcc"], *TARGETS[build.target], "-nostdlib",
                           "-Wl,--gc-sections", "-Wl,-e,mcu_eval", str(build.obj), "-lm",
                           "-lgcc", "-o", str(Path(out))], capture_output=True, text=True)
    if done.returncode == 0:
        return []
    found = re.findall(r"undefined reference to `([^']+)'", done.stderr)
    if not found:
        raise ExportError(f"link of {build.obj} failed: {done.stderr.strip()}")
    return sorted(set(found))


def _write_wrapper(header_text: str, out: Path, prefix: str, has_proxies: bool,
                   recurrent: bool) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "model.h").write_text(header_text)
    # a recurrent model's one step: from a state held here (.c_recurrent)
    evaluate = ("PFX_compensate_state(s, mcu_h, mcu_h_out, raw, comp, drift)" if recurrent
                else "PFX_compensate(s, raw, comp, drift)")
    wrapper = _WRAPPER.replace("PFX_EVAL", evaluate)
    if recurrent:
        wrapper = wrapper.replace("int mcu_eval(const float *s", "float mcu_h[PFX_GRU_HIDDEN], "
                                  "mcu_h_out[PFX_GRU_HIDDEN];\nint mcu_eval(const float *s", 1)
    (out / "mcu.c").write_text(wrapper.replace("PROXY_ARG", "mcu_prox," if has_proxies else "")
                               .replace("PFX_N_", f"{prefix.upper()}_N_")
                               .replace("PFX_GRU_", f"{prefix.upper()}_GRU_")
                               .replace("PFX", prefix))


@dataclass
class Run:
    """What one emulated call returned and cost."""

    ret: int
    compensated: np.ndarray
    drift: np.ndarray
    flag: int
    instructions: int = 0
    by_function: dict[str, int] = field(default_factory=dict)


class Emulator:
    """A :class:`CrossBuild` linked and run under ``unicorn`` on a Cortex-M4 with its FPU.

    Parameters
    ----------
    build : CrossBuild
        Built for ``cortex-m4f`` (the emulated core: Cortex-M4 with its FPU) or
        ``cortex-m0plus`` (ARMv6-M, a subset of the M4's ARMv7E-M: the same core runs it).
    n_signals, n_axes : int
    """

    RAM = 0x10000
    RAM_SIZE = 0x100000
    STACK_TOP = RAM + RAM_SIZE - 0x100
    SCRATCH = RAM + RAM_SIZE - 0x40000      # argument buffers of mcu_eval
    RETURN = 0x200                          # the sentinel return address (not mapped code)

    def __init__(self, build: CrossBuild, n_signals: int, n_axes: int) -> None:
        if build.target not in ("cortex-m4f", "cortex-m0plus"):
            raise ExportError("the emulator runs cortex-m4f and cortex-m0plus builds")
        from unicorn import UC_ARCH_ARM, UC_HOOK_CODE, UC_MODE_MCLASS, UC_MODE_THUMB, Uc
        from unicorn import arm_const as arm

        tools = toolchain()
        self._arm = arm
        self.n_signals, self.n_axes = n_signals, n_axes
        self.real_double = "-DTHERMONET_USE_DOUBLE" in build.flags
        self._fmt = "d" if self.real_double else "f"
        self._size = 8 if self.real_double else 4
        with tempfile.TemporaryDirectory() as tmp_dir:
            tmp = Path(tmp_dir)
            (tmp / "link.ld").write_text(_LINK_SCRIPT)
            elf, image = tmp / "mcu.elf", tmp / "mcu.bin"
            _run([tools["gcc"], *TARGETS[build.target], "-nostartfiles", "-specs=nosys.specs",
                  "-T", str(tmp / "link.ld"), str(build.obj), "-lm", "-lgcc", "-lc", "-lgcc",
                  "-o", str(elf)], "arm-none-eabi-gcc (link)")
            _run([tools["objcopy"], "-O", "binary", str(elf), str(image)], "objcopy")
            code = image.read_bytes()
            symbols = _run([tools["nm"], "-S", "-n", str(elf)], "nm")
            own = _run([tools["nm"], "--defined-only", str(build.obj)], "nm")
        #: the object's own functions (the header and the entry points); the rest is libraries
        self.own = {ln.split()[-1] for ln in own.splitlines() if len(ln.split()) == 3
                    and ln.split()[1] in "tT"}
        self.image_bytes = len(code)
        self.sym: dict[str, int] = {}
        funcs: list[tuple[int, int, str]] = []
        for ln in symbols.splitlines():
            parts = ln.split()
            if len(parts) == 4:
                addr, size, kind, name = int(parts[0], 16), int(parts[1], 16), parts[2], parts[3]
                self.sym[name] = addr & ~1
                if kind in "tT":
                    funcs.append((addr & ~1, size, name))
            elif len(parts) == 3:
                self.sym[parts[2]] = int(parts[0], 16) & ~1
        funcs.sort()
        self._func_start = [f[0] for f in funcs]
        self._funcs = funcs
        self.library_code_bytes = sum(s for _, s, n in funcs if n not in self.own)
        self.uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        self.uc.mem_map(0, self.RAM + self.RAM_SIZE)
        self.uc.mem_write(self.RAM, code)
        self._counts: dict[int, int] = {}
        self._counting = False
        self._hook_kind = UC_HOOK_CODE
        self._hook: Any = None
        self._call("mcu_init")

    # -------------------------------------------------------------- low level
    def _call(self, name: str, args: tuple[int, ...] = (), *, count: bool = False) -> int:
        arm = self._arm
        regs = (arm.UC_ARM_REG_R0, arm.UC_ARM_REG_R1, arm.UC_ARM_REG_R2, arm.UC_ARM_REG_R3)
        for reg, value in zip(regs, args, strict=False):
            self.uc.reg_write(reg, value)
        self.uc.reg_write(arm.UC_ARM_REG_SP, self.STACK_TOP)
        self.uc.reg_write(arm.UC_ARM_REG_LR, self.RETURN | 1)
        hook = None
        if count:
            counts = self._counts = {}

            def on_code(uc: Any, address: int, size: int, data: Any) -> None:
                counts[address] = counts.get(address, 0) + 1

            hook = self.uc.hook_add(self._hook_kind, on_code)
        try:
            self.uc.emu_start(self.sym[name] | 1, self.RETURN, count=50_000_000)
        finally:
            if hook is not None:
                self.uc.hook_del(hook)
        if self.uc.reg_read(arm.UC_ARM_REG_PC) & ~1 != self.RETURN:
            raise ExportError(f"emulated {name} did not return")
        return int(self.uc.reg_read(arm.UC_ARM_REG_R0))

    def _attribute(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for address, n in self._counts.items():
            k = bisect.bisect_right(self._func_start, address) - 1
            name = self._funcs[k][2] if k >= 0 else "?"
            out[name] = out.get(name, 0) + n
        return out

    def _reals(self, values: np.ndarray) -> bytes:
        return struct.pack(f"<{len(values)}{self._fmt}", *(float(v) for v in values))

    def _read_reals(self, address: int) -> np.ndarray:
        raw = self.uc.mem_read(address, self._size * self.n_axes)
        return np.array(struct.unpack(f"<{self.n_axes}{self._fmt}", bytes(raw)))

    def _read_int(self, name: str) -> int:
        return int(struct.unpack("<i", bytes(self.uc.mem_read(self.sym[name], 4)))[0])

    def _run_result(self, ret: int, comp: int, drift: int, flag: int, count: bool) -> Run:
        run = Run(ret, self._read_reals(comp), self._read_reals(drift), flag)
        if count:
            run.by_function = self._attribute()
            run.instructions = sum(run.by_function.values())
        return run

    # -------------------------------------------------------------- calls
    def evaluate(self, signals: np.ndarray, raw: np.ndarray, *, count: bool = False) -> Run:
        """``<prefix>_compensate(signals, raw, compensated, drift)`` on the part."""
        s_addr = self.SCRATCH
        r_addr = s_addr + 4 * self.n_signals + 8 - (4 * self.n_signals) % 8
        c_addr = r_addr + self._size * self.n_axes
        d_addr = c_addr + self._size * self.n_axes
        self.uc.mem_write(s_addr, struct.pack(f"<{self.n_signals}f",
                                              *(float(v) for v in signals)))
        self.uc.mem_write(r_addr, self._reals(np.asarray(raw)))
        flag = self._call("mcu_eval", (s_addr, r_addr, c_addr, d_addr), count=count)
        return self._run_result(flag, c_addr, d_addr, flag, count)

    def step(self, time: float | int, temperature_c: float, raw: np.ndarray,
             proxies: np.ndarray | None = None, *, count: bool = False) -> Run:
        """``<prefix>_step`` on the emulated state; ``time`` in the header's time type
        (microseconds, an int, on the float path; seconds on the double path)."""
        time_fmt = "<Q" if isinstance(time, (int, np.integer)) else "<d"
        self.uc.mem_write(self.sym["mcu_time"], struct.pack(time_fmt, time))
        self.uc.mem_write(self.sym["mcu_temp"], struct.pack("<f", float(temperature_c)))
        if proxies is not None and len(proxies):
            self.uc.mem_write(self.sym["mcu_prox"], struct.pack(
                f"<{len(proxies)}f", *(float(v) for v in proxies)))
        self.uc.mem_write(self.sym["mcu_raw"], self._reals(np.asarray(raw)))
        self._call("mcu_step", count=count)
        return self._run_result(self._read_int("mcu_ret"), self.sym["mcu_comp"],
                                self.sym["mcu_drift"], self._read_int("mcu_flag"), count)

    def function_kind(self, name: str) -> str:
        """``header`` (the header's own code), ``soft-double``, ``libm`` or ``other``."""
        if name in self.own:
            return "header"
        if _SOFT_DOUBLE.match(name):
            return "soft-double"
        if _LIBM.match(name) or name.startswith("__ieee754") or name.startswith("__kernel"):
            return "libm"
        return "other"
