"""Where a CPU kernel's time goes, instruction by instruction: ``perf`` samples in numba's code.

numba compiles into anonymous memory, which ``perf`` cannot name or disassemble. ``run``
steps one case of ``bench_extensions.py`` and, before it exits, writes every anonymous
executable region of its memory into a folder, a file per region named by its start
address; ``annotate`` counts ``perf``'s samples per region and per block of the hottest
region, and with ``--listing`` writes its instructions (``objdump``), each with its share::

    perf record -e cpu-clock -F 4000 -o /tmp/cohesion.data \\
        python benchmarks/jit_profile.py run cohesion --warm 200 --steps 200 --dump /tmp/cohesion
    python benchmarks/jit_profile.py annotate /tmp/cohesion.data /tmp/cohesion --listing /tmp/cohesion.asm

The kernels load from numba's cache as usual (run the case once beforehand so that the
samples are not of the compiler). ``cpu-clock`` needs no hardware counters (virtual
machines have none); ``perf_event_paranoid`` must allow sampling one's own process (2 does).
A block's share is where the processor stood when sampled, so a long operation's cost
shows on the instructions just after it. docs/performance.md (2026-11-27) has an example.
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import subprocess
import time

from bench_extensions import backend, cases


def dump_code(folder: str) -> list[tuple[int, int]]:
    """Write each anonymous executable region of this process's memory (where numba's
    code is) to ``folder/<start in hex>.bin``; returns their ``(start, size)``."""
    os.makedirs(folder, exist_ok=True)
    found = []
    with open("/proc/self/maps") as maps, open("/proc/self/mem", "rb") as mem:
        for line in maps:
            fields = line.split()
            if "x" not in fields[1] or (len(fields) > 5 and not fields[5].startswith("[anon")):
                continue
            start, end = (int(v, 16) for v in fields[0].split("-"))
            mem.seek(start)
            try:
                code = mem.read(end - start)
            except OSError:  # a guard page, or memory unmapped meanwhile
                continue
            with open(os.path.join(folder, f"{start:x}.bin"), "wb") as out:
                out.write(code)
            found.append((start, end - start))
    return found


def regions(folder: str) -> list[tuple[int, int, str]]:
    """The regions :func:`dump_code` wrote: ``(start, size, path)``, by address."""
    out = []
    for name in os.listdir(folder):
        if re.fullmatch(r"[0-9a-f]+\.bin", name):
            path = os.path.join(folder, name)
            out.append((int(name[:-4], 16), os.path.getsize(path), path))
    return sorted(out)


def sample_addresses(data: str) -> list[int]:
    """The instruction address of every sample in the ``perf`` recording ``data``."""
    text = subprocess.run(["perf", "script", "-F", "ip", "-i", data], capture_output=True, text=True,
                          check=True).stdout
    return [int(word, 16) for word in text.split()]


def per_region(addresses, found) -> collections.Counter:
    """How many of ``addresses`` fall in each region of ``found`` (keyed by its start)."""
    counts = collections.Counter()
    for address in addresses:
        for start, size, _ in found:
            if start <= address < start + size:
                counts[start] += 1
                break
    return counts


def per_block(addresses, start: int, size: int, width: int = 256) -> collections.Counter:
    """How many of ``addresses`` fall in each block of ``width`` bytes of the region at
    ``start`` (keyed by the block's offset in the region)."""
    return collections.Counter((a - start) // width * width for a in addresses if start <= a < start + size)


def listing(path: str, start: int, addresses, total: int) -> list[str]:
    """The region at ``start`` (its bytes in ``path``) disassembled by ``objdump``, a line
    per instruction: its share of ``total`` samples in per cent, its offset, the
    instruction."""
    text = subprocess.run(["objdump", "-D", "-b", "binary", "-mi386:x86-64", f"--adjust-vma={start:#x}",
                           "--no-show-raw-insn", path], capture_output=True, text=True, check=True).stdout
    counts = collections.Counter(addresses)
    out = []
    for line in text.splitlines():
        m = re.match(r"\s*([0-9a-f]+):\s+(.*)", line)
        if m:
            address = int(m.group(1), 16)
            out.append(f"{100 * counts[address] / total:6.2f} {address - start:7x}  {m.group(2)}")
    return out


def run(case: str, warm: int, steps: int, n: int, dim: int, folder: str) -> None:
    """Step ``case`` of ``bench_extensions.py`` ``warm`` steps, then ``steps`` timed, then
    dump the code (:func:`dump_code`)."""
    stepped = backend(cases(n, 2.0, dim)[case], n, 2.0, dim)
    stepped.advance(warm)
    begin = time.perf_counter()
    stepped.advance(steps)
    seconds = time.perf_counter() - begin
    print(f"{case}: {steps * n / seconds:.3g} particle-steps/s over {steps} steps after {warm}")
    print(f"{len(dump_code(folder))} regions of code written to {folder}")


def annotate(data: str, folder: str, listing_path: str | None, width: int) -> None:
    """Print each region's share of the samples and the hottest region's blocks over 1 %."""
    addresses = sample_addresses(data)
    found = regions(folder)
    counts = per_region(addresses, found)
    total = len(addresses)
    print(f"{total} samples; in the dumped regions {sum(counts.values())}")
    for start, size, _ in found:
        if counts[start]:
            print(f"  region {start:x} ({size} bytes): {100 * counts[start] / total:.1f} %")
    if not counts:
        return
    start, size, path = next(r for r in found if r[0] == counts.most_common(1)[0][0])
    print(f"blocks of {width} bytes of region {start:x} with more than 1 % of the samples:")
    for offset, count in sorted(per_block(addresses, start, size, width).items()):
        if count > total / 100:
            print(f"  {offset:7x}  {100 * count / total:5.1f} %")
    if listing_path:
        with open(listing_path, "w") as out:
            out.write("\n".join(listing(path, start, addresses, total)) + "\n")
        print(f"instructions of region {start:x}, each with its share in per cent: {listing_path}")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="step a case, then dump numba's code")
    r.add_argument("case", help="a case of bench_extensions.py, e.g. plain or cohesion")
    r.add_argument("--warm", type=int, default=200, help="steps before the timed ones")
    r.add_argument("--steps", type=int, default=200)
    r.add_argument("--n", type=int, default=100_000)
    r.add_argument("--dim", type=int, choices=(2, 3), default=2)
    r.add_argument("--dump", required=True, help="folder for the regions of code")
    a = sub.add_parser("annotate", help="count perf's samples in the dumped code")
    a.add_argument("data", help="perf's recording (perf record -o)")
    a.add_argument("dump", help="the folder that run wrote")
    a.add_argument("--listing", help="write the hottest region's instructions, with shares, here")
    a.add_argument("--block", type=int, default=256, help="bytes per block")
    args = parser.parse_args(argv)
    if args.command == "run":
        run(args.case, args.warm, args.steps, args.n, args.dim, args.dump)
    else:
        annotate(args.data, args.dump, args.listing, args.block)


if __name__ == "__main__":
    main()
