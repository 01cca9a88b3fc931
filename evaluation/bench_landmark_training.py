"""Training throughput of the landmark network on this machine's CPU: float32 against bf16
autocast, with and without channels-last, side by side in one process (the CPU recipe's
choice of precision, docs/landmark_net.md).

Each setting: the default :class:`neural.landmarks.network.LandmarkConfig` network, random
batches of ``--batch-size`` 128-px crops (the batch drawing is not timed), one warm-up step,
then ``--steps`` AdamW steps on the Gaussian NLL; images/s = batch x steps / process CPU
seconds x threads (CPU seconds, not wall: other jobs on a shared machine slow the wall clock
but not the work), and wall images/s beside it. Command::

    python -m evaluation.bench_landmark_training --steps 5 --report reports/bench_landmark_training.json

``--widths 24 48 96 160 256 --blocks 0 1 1 1 1 --precision float32`` times another network.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

from morphable.errors import InputError, one_line_errors

SETTINGS = (("float32", False), ("float32", True), ("bf16", False), ("bf16", True))


def time_setting(amp: str, channels_last: bool, steps: int, batch_size: int, threads: int,
                 widths=None, blocks=None) -> dict:
    import torch

    from neural.landmarks.network import LandmarkConfig, LandmarkNet, gaussian_nll

    torch.manual_seed(0)
    torch.set_num_threads(threads)
    cfg = LandmarkConfig(batch_size=batch_size)
    if widths is not None:
        cfg = LandmarkConfig(batch_size=batch_size, widths=tuple(widths), blocks=tuple(blocks))
    net = LandmarkNet(cfg)
    x = torch.randn(batch_size, 3, cfg.resolution, cfg.resolution)
    if channels_last:
        net, x = net.to(memory_format=torch.channels_last), x.to(memory_format=torch.channels_last)
    target, weight = torch.randn(batch_size, cfg.n_points, 2), torch.ones(batch_size, cfg.n_points)
    opt = torch.optim.AdamW(net.parameters(), lr=1e-3)

    def step():
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=amp == "bf16"):
            out = net(x)
        loss = gaussian_nll(out["points"], out["log_sigma"], target, weight)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    step()
    c0, w0 = time.process_time(), time.perf_counter()
    for _ in range(steps):
        step()
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    images = steps * batch_size
    return {"amp": amp, "channels_last": channels_last,
            "images_per_cpu_second_x_threads": round(images / cpu * threads, 1),
            "images_per_wall_second": round(images / wall, 1)}


@one_line_errors("python -m evaluation.bench_landmark_training")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=5)
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--widths", type=int, nargs="+", help="another network's stage widths")
    p.add_argument("--blocks", type=int, nargs="+", help="... and its residual blocks per stage")
    p.add_argument("--precision", choices=("all", "float32"), default="all",
                   help="float32: only float32 with channels-last (the CPU recipe's setting)")
    p.add_argument("--report", help="output JSON")
    args = p.parse_args(argv)
    if (args.widths is None) != (args.blocks is None) or (
            args.widths is not None and len(args.widths) != len(args.blocks)):
        raise InputError("--widths and --blocks go together, one block count per width")
    settings = SETTINGS if args.precision == "all" else (("float32", True),)
    rows = [time_setting(a, c, args.steps, args.batch_size, args.threads, args.widths, args.blocks)
            for a, c in settings]
    print("| precision | channels-last | img/s (CPU time x threads) | img/s (wall) |")
    print("| --- | --- | --- | --- |")
    for r in rows:
        print(f"| {r['amp']} | {'yes' if r['channels_last'] else 'no'} | "
              f"{r['images_per_cpu_second_x_threads']} | {r['images_per_wall_second']} |")
    if args.report:
        from morphable.io.atomic import write_json

        write_json(args.report, {"steps": args.steps, "batch_size": args.batch_size,
                                 "widths": args.widths, "blocks": args.blocks,
                                 "threads": args.threads, "rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
