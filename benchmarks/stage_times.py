"""Where one ``mdvae`` command's wall time goes: the command run in this process with a timer
around each stage (reading and retargeting a file, denoising, the foot lock, the way back and
writing), printed as a table of when each stage started and how long it took, and on which
thread (a long take's pieces and chunks run side by side).

The stages are wrapped as their modules load, so the command runs as it does from the shell:
nothing that it would load later is loaded first (``mdvae denoise`` reads its first BVH takes
in a child process while torch loads, and would not if torch were loaded already). The table
is printed when the process ends (the command ends with ``os._exit`` after its exit handlers).

    python benchmarks/stage_times.py denoise take.bvh -o clean.bvh
    python benchmarks/stage_times.py --all denoise take.bvh -o clean.bvh   # every chunk too
"""

from __future__ import annotations

import atexit
import importlib.abc
import sys
import threading
import time

#: module -> the functions timed in it: the stages of ``mdvae denoise``
STAGES = {
    "mdvae_cli.run.denoise_files": ("read_file", "_denoise_group", "write_file"),
    "mdvae_cli.retarget.retarget": ("retarget",),
    "mdvae_cli.retarget.pose_solve": ("solve_frames",),
    "mdvae_cli.infer.native_rate": ("to_model_rate", "to_input_rate"),
    "mdvae_cli.infer.window_groups": ("make_windows",),
    "mdvae_cli.infer.denoise": ("refine_windows",),
    "mdvae_cli.infer.noise_blend": ("blend_motion",),
    "mdvae_cli.infer.feet": ("lock_motions",),
    "mdvae_cli.retarget.way_back": ("write_back_data", "_write_back_rows"),
    "mdvae_cli.formats.bvh_write": ("write_bvh",),
}
#: stages that run once per chunk of frames: summed unless --all
CHUNKED = {"solve_frames", "_write_back_rows"}

T0 = time.perf_counter()
LOG: list[tuple[str, float, float, str]] = []


def timed(module, name: str) -> None:
    """Replace ``module.name`` by a function that logs when it ran (calls from the module
    itself go through its globals, so they are timed too)."""
    inner = getattr(module, name)

    def run(*args, **kwargs):
        start = time.perf_counter()
        try:
            return inner(*args, **kwargs)
        finally:
            thread = threading.current_thread().name
            LOG.append((name, start - T0, time.perf_counter() - start, thread))

    setattr(module, name, run)


class _Wrapper(importlib.abc.MetaPathFinder):
    """Wraps the stages of a module of :data:`STAGES` right after it is executed."""

    def find_spec(self, fullname, path, target=None):
        if fullname not in STAGES:
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(fullname, path, target)
            if spec is not None:
                break
        else:
            return None
        execute = spec.loader.exec_module

        def exec_module(module):
            execute(module)
            for name in STAGES[fullname]:
                if hasattr(module, name):
                    timed(module, name)

        spec.loader.exec_module = exec_module
        return spec


def table(log: list[tuple[str, float, float, str]], every_chunk: bool) -> str:
    """The stages as a markdown table, in the order they started."""
    rows, chunks = [], {}
    for name, start, took, thread in sorted(log, key=lambda r: r[1]):
        if name in CHUNKED and not every_chunk:
            first, last, total, count = chunks.get(name, (start, 0.0, 0.0, 0))
            chunks[name] = (first, max(last, start + took), total + took, count + 1)
            continue
        rows.append(f"| {name} | {start:.2f} | {took:.2f} | {thread} |")
    for name, (first, last, total, count) in chunks.items():
        rows.append(f"| {name}: {count} chunks, {total:.2f} s of their own | {first:.2f} | "
                    f"{last - first:.2f} | workers |")  # fmt: skip
    head = "| stage | started (s) | took (s) | thread |\n|---|---|---|---|"
    return "\n".join(
        [head, *rows, f"| the whole process | 0.00 | {time.perf_counter() - T0:.2f} | |"]
    )


def main() -> None:
    args = sys.argv[1:]
    every_chunk = "--all" in args[:1]
    if every_chunk:
        args = args[1:]
    sys.meta_path.insert(0, _Wrapper())
    atexit.register(lambda: print(table(LOG, every_chunk), file=sys.stderr))
    sys.argv = ["mdvae", *args]
    from mdvae_cli.cli.main import main as mdvae

    mdvae()


if __name__ == "__main__":
    main()
