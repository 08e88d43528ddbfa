"""Machine instructions per bus-step inside the compiled kernel, counted exactly (not timed).

    python -m benchmarks.kernel_instructions             # 12 m bus, SORT 2 day (about 1 min)
    python -m benchmarks.kernel_instructions --bus 18m --hours 2

Timings on a shared VM drift by 30 % within an hour; an instruction count does not. The script
runs itself under valgrind's callgrind with ``--dump-instr=yes``, reads the cost of every
instruction address inside the kernel's machine code (dumped by the child, since JIT code has
no symbols), and prints instructions per bus-step with a breakdown by opcode. Fewer
instructions are not always less time (docs/performance.md), so confirm a change
with timings taken in one run. Needs valgrind and objdump on the PATH; not run in CI. The
first run takes longer: numba compiles the kernel again for valgrind's virtual CPU.
"""

from __future__ import annotations

import argparse
import collections
import ctypes
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

CODE_BYTES = 60_000  # more than the kernel's machine code; only addresses counted matter


def child(bus_name: str, hours: float, out: Path) -> None:
    """Under valgrind: compile (or load) the kernel, dump its code, run the day once."""
    from ebus_env.config import load_bus
    from ebus_env.cycles import service_day

    bus = load_bus(bus_name)
    model = bus.build()
    day = service_day("sort2", hours, model.dt_s, bus.service)
    model.simulate(day, soc_start=0.95, record=False)  # compiles or loads; dispatch resolved
    kernel = model.kernel("run")
    compiled = kernel.overloads[kernel.signatures[0]]
    address = compiled.library.get_pointer_to_function(compiled.fndesc.llvm_func_name)
    (out / "code.bin").write_bytes(ctypes.string_at(address, CODE_BYTES))
    (out / "meta.txt").write_text(f"{address} {day.n_steps}")
    model.simulate(day, soc_start=0.95, record=False)


def costs_by_address(callgrind_out: Path, lo: int, hi: int) -> dict[int, int]:
    """Self cost (Ir) of each instruction address in [lo, hi) from a callgrind file (addresses
    may be written relative to the previous line; a line after ``calls=`` is a call's
    inclusive cost and is skipped)."""
    costs: dict[int, int] = collections.defaultdict(int)
    address, after_call = 0, False
    for line in callgrind_out.read_text().splitlines():
        if line.startswith("calls="):
            after_call = True
            continue
        m = re.match(r"^(0x[0-9a-f]+|[+-]\d+|\*)\s+\S+\s+(\d+)", line)
        if not m:
            continue
        pos, cost = m.groups()
        if pos.startswith("0x"):
            address = int(pos, 16)
        elif pos[0] in "+-":
            address += int(pos)
        if after_call:
            after_call = False
        elif lo <= address < hi:
            costs[address - lo] += int(cost)
    return costs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bus", default="12m")
    parser.add_argument("--hours", type=float, default=13.5)
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.bus, args.hours, Path(args.child))
        return
    for tool in ("valgrind", "objdump"):
        if shutil.which(tool) is None:
            raise SystemExit(f"{tool} is not on the PATH; install it to count instructions.")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        subprocess.run(["valgrind", "--tool=callgrind", "--dump-instr=yes",
                        f"--callgrind-out-file={out / 'callgrind.out'}", sys.executable,
                        __file__, "--bus", args.bus, "--hours", str(args.hours),
                        "--child", str(out)],
                       check=True, capture_output=True, env={**os.environ, "PYTHONHASHSEED": "0"})
        address, n_steps = map(int, (out / "meta.txt").read_text().split())
        costs = costs_by_address(out / "callgrind.out", address, address + CODE_BYTES)
        listing = subprocess.run(["objdump", "-D", "-b", "binary", "-mi386:x86-64",
                                  str(out / "code.bin")], capture_output=True, text=True,
                                 check=True).stdout
    runs = 2 * n_steps  # the child simulates the day twice
    by_opcode: dict[str, float] = collections.Counter()
    for line in listing.splitlines():
        m = re.match(r"\s*([0-9a-f]+):\s+(?:[0-9a-f]{2} )+\s*(\S+)", line)
        if m and int(m.group(1), 16) in costs:
            by_opcode[m.group(2)] += costs[int(m.group(1), 16)] / runs
    total = sum(by_opcode.values())
    print(f"{args.bus} bus, SORT 2, {args.hours} h: {total:.1f} instructions per bus-step "
          "inside the kernel")
    for opcode, count in sorted(by_opcode.items(), key=lambda kv: -kv[1])[:15]:
        print(f"  {opcode:12s} {count:6.1f}")


if __name__ == "__main__":
    main()
