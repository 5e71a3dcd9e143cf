"""PyTorch peer for bench/unet_vs_torch.cpp: times the identical UNet in PyTorch.

Run by bench_unet_vs_torch as a subprocess (OMP_NUM_THREADS set, OPENBLAS_CORETYPE and
OPENBLAS_L2_SIZE unset for this process only); by hand:
    OMP_NUM_THREADS=2 /usr/bin/python3 bench/torch_unet_bench.py --threads 2 --rows 64
Prints human-readable notes on stderr and one JSON object on the last stdout line:
    {"train_b1": s, "train_b4": s, "infer_b1": s, "infer_b4": s, "blas": [...], "conv_ops": [...], ...}
Each time is the median over --reps after --warmup untimed runs (and <row>_min the fastest);
<row>_cpu is the median process CPU time of one run (all threads), the lowest over the settings.
Every row is timed under each of --settings (default: all three) and the fastest is reported,
so the peer is measured at its best:
  default        torch's defaults (oneDNN convolutions where torch picks them, NCHW)
  no_onednn      torch.backends.mkldnn.enabled = False (im2col + BLAS convolutions)
  channels_last  model and input in channels_last memory format (oneDNN's preferred layout)
With --bf16 also infer_b1_bf16 / infer_b4_bf16: inference under torch.autocast("cpu",
dtype=torch.bfloat16) (the default and channels_last settings; null where autocast fails).
"""
import argparse
import json
import os
import statistics
import sys
import time

import torch

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "fixtures"))
import torch_unet  # noqa: E402


def timed(fn, warmup, reps):
    for _ in range(warmup):
        fn()
    times, cpu = [], []
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(times), min(times), statistics.median(cpu)


def make_batch(n, rows, cols, in_channels, seed):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn((n, in_channels, rows, cols), generator=g)
    target = torch.rand((n, 1, rows, cols), generator=g)
    mask = (torch.rand((n, 1, rows, cols), generator=g) < 0.7).float()
    return x, target, mask


def measure(args, model, opt, channels_last):
    fmt = torch.channels_last if channels_last else torch.contiguous_format
    model.to(memory_format=fmt)
    out = {}
    for n in (1, 4):
        x, target, mask = make_batch(n, args.rows, args.cols, args.in_channels, seed=n)
        x = x.contiguous(memory_format=fmt)

        def train_step():
            opt.zero_grad(set_to_none=False)
            pred = model(x)
            loss, _, _ = torch_unet.loss_fn(model, pred, target, mask, args.lam)
            loss.backward()
            opt.step()

        out[f"train_b{n}"], out[f"train_b{n}_min"], out[f"train_b{n}_cpu"] = timed(train_step, args.warmup, args.reps)
    for n in (1, 4):
        x, _, _ = make_batch(n, args.rows, args.cols, args.in_channels, seed=n)
        x = x.contiguous(memory_format=fmt)

        def infer():
            with torch.no_grad():
                model(x)

        out[f"infer_b{n}"], out[f"infer_b{n}_min"], out[f"infer_b{n}_cpu"] = timed(infer, args.warmup, args.reps)
        if args.bf16 and torch.backends.mkldnn.enabled:

            def infer_bf16():
                with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
                    model(x)

            try:
                row = f"infer_b{n}_bf16"
                out[row], out[row + "_min"], out[row + "_cpu"] = timed(infer_bf16, args.warmup, args.reps)
            except Exception as e:  # noqa: BLE001 - reported, the fp32 rows still count
                print(f"torch bf16 autocast failed: {e}", file=sys.stderr)
    return out


def loaded_libraries(patterns):
    with open("/proc/self/maps") as f:
        paths = {line.split()[-1] for line in f if "/" in line}
    return sorted(p for p in paths if any(s in os.path.basename(p) for s in patterns))


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--rows", type=int, default=64)
    p.add_argument("--cols", type=int, default=1024)
    p.add_argument("--in-channels", type=int, default=3)
    p.add_argument("--base", type=int, default=16)
    p.add_argument("--depth", type=int, default=4)
    p.add_argument("--lam", type=float, default=1e-4)
    p.add_argument("--reps", type=int, default=7)
    p.add_argument("--warmup", type=int, default=2)
    p.add_argument("--settings", default="default,no_onednn,channels_last",
                   help="comma-separated subset of default, no_onednn, channels_last")
    p.add_argument("--bf16", action="store_true", help="also time bf16 autocast inference")
    args = p.parse_args()

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    model = torch_unet.UNet(args.in_channels, 1, args.base, args.depth)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)

    # Which kernels run: convolution ops seen by the profiler in one training step.
    x, target, mask = make_batch(1, args.rows, args.cols, args.in_channels, seed=1)
    with torch.autograd.profiler.profile() as prof:
        loss, _, _ = torch_unet.loss_fn(model, model(x), target, mask, args.lam)
        loss.backward()
    conv_ops = sorted({e.name for e in prof.function_events if "conv" in e.name})

    per_setting = {}
    for setting in args.settings.split(","):
        if setting not in ("default", "no_onednn", "channels_last"):
            sys.exit(f"error: --settings: unknown setting {setting!r}")
        torch.backends.mkldnn.enabled = setting != "no_onednn"
        per_setting[setting] = measure(args, model, opt, channels_last=setting == "channels_last")
        print(f"torch {setting}: {per_setting[setting]}", file=sys.stderr)
    torch.backends.mkldnn.enabled = True
    best = {}
    for row in ("infer_b1_bf16", "infer_b4_bf16") if args.bf16 else ():
        have = [k for k in per_setting if row in per_setting[k]]
        if not have:
            best[row] = None
            continue
        key = min(have, key=lambda k: per_setting[k][row])
        best[row] = per_setting[key][row]
        best[row + "_min"] = per_setting[key][row + "_min"]
        best[row + "_setting"] = key
        best[row + "_cpu"] = min(per_setting[k][row + "_cpu"] for k in have)
    for row in ("train_b1", "train_b4", "infer_b1", "infer_b4"):
        key = min(per_setting, key=lambda k: per_setting[k][row])
        best[row] = per_setting[key][row]
        best[row + "_min"] = per_setting[key][row + "_min"]
        best[row + "_setting"] = key
        best[row + "_cpu"] = min(per_setting[k][row + "_cpu"] for k in per_setting)

    result = dict(best)
    result["all"] = per_setting
    result["torch_version"] = torch.__version__
    result["threads"] = torch.get_num_threads()
    result["blas"] = loaded_libraries(["blas", "lapack"])
    result["dnnl"] = loaded_libraries(["dnnl"])
    result["conv_ops"] = conv_ops
    result["blas_info"] = [s.strip() for s in torch.__config__.show().split(",") if "BLAS_INFO" in s]
    result["env"] = {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE")}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
