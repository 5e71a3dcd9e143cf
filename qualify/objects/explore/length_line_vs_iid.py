#!/usr/bin/env python3
"""Can a histogram of ~20 held-out tracks tell a good size-error model from a Gaussian iid one?

A check outside the engine (numpy only), on the data `lidar-qualify objects` judges: the KITTI
tracking validation sequences with PointRCNN detections (score > 0, nearest detection within 2 m in
the bird's-eye view; the engine's association differs in detail). For one class and box dimension,
two-fold cross-fit by sequence parity as the engine's held-out table: fit on one half, simulate the
other half's matched frames 32 times, pool both folds, and compare with the measured errors by the
histogram intersection of qualify/similarity.h (40 equal bins over the pooled 1st-99th percentile,
one overflow bin each side).

  line: error = a + b (true size - mean true size) + N(0, residual sd), a and b least squares on
        the fit half (the detector regressing box sizes towards its prior);
  iid:  error = N(mean, sd) of the fit half.

Prints per fold the slope, the held-out RMS of the error about each model's prediction, and the
intersections. Usage: length_line_vs_iid.py [DATA_DIR] [CLASS] [DIM: l|w|h]
"""
import collections
import sys

import numpy as np

DATA = sys.argv[1] if len(sys.argv) > 1 else "../shared/data/kitti-tracking-gt-pointrcnn"
CLS = sys.argv[2] if len(sys.argv) > 2 else "Cyclist"
DIM = sys.argv[3] if len(sys.argv) > 3 else "l"
HALVES = {"even": ["0001", "0008", "0012", "0014", "0019"], "odd": ["0006", "0010", "0013", "0016"]}


def matched(seqs):
    """(true size, detected - true) per matched frame of class CLS."""
    label_col = {"l": 12, "w": 11, "h": 10}[DIM]  # KITTI tracking labels: h w l at 10 11 12
    det_col = {"l": 9, "w": 8, "h": 7}[DIM]       # AB3DMOT detections: h w l at 7 8 9
    rows = []
    for s in seqs:
        truth = collections.defaultdict(list)
        for line in open(f"{DATA}/label_02/{s}.txt"):
            f = line.split()
            if f[2] == CLS:
                truth[int(f[0])].append((float(f[label_col]), float(f[13]), float(f[15])))
        dets = collections.defaultdict(list)
        for line in open(f"{DATA}/detection/pointrcnn_{CLS}_val/{s}.txt"):
            f = line.strip().split(",")
            if float(f[6]) > 0:
                dets[int(f[0])].append((float(f[det_col]), float(f[10]), float(f[12])))
        for frame, objects in truth.items():
            for size, x, z in objects:
                near = [(np.hypot(d[1] - x, d[2] - z), d[0]) for d in dets.get(frame, [])]
                near = [n for n in near if n[0] < 2]
                if near:
                    rows.append((size, min(near)[1] - size))
    return np.array(rows)


def intersection(a, b, bins=40):
    lo, hi = np.percentile(np.concatenate([a, b]), [1, 99])
    hi = np.nextafter(hi, hi + 1)
    width = (hi - lo) / bins

    def hist(v):
        i = np.clip(np.floor((v - lo) / width).astype(int) + 1, 1, bins)
        i[v < lo], i[v >= hi] = 0, bins + 1
        return np.bincount(i, minlength=bins + 2) / len(v)

    return np.minimum(hist(a), hist(b)).sum()


def main():
    data = {k: matched(v) for k, v in HALVES.items()}
    rng = np.random.default_rng(0)
    measured, line_sim, iid_sim = [], [], []
    for fit, judge in (("even", "odd"), ("odd", "even")):
        F, J = data[fit], data[judge]
        centre = F[:, 0].mean()
        slope, intercept = np.polyfit(F[:, 0] - centre, F[:, 1], 1)
        resid_sd = (F[:, 1] - intercept - slope * (F[:, 0] - centre)).std()
        pred = intercept + slope * (J[:, 0] - centre)
        line = np.concatenate([pred + resid_sd * rng.standard_normal(len(J)) for _ in range(32)])
        iid = np.concatenate([F[:, 1].mean() + F[:, 1].std() * rng.standard_normal(len(J)) for _ in range(32)])
        print(f"fit {fit} -> judge {judge}: slope {slope:+.3f}; held-out RMS about the prediction: "
              f"line {np.sqrt(np.mean((J[:, 1] - pred) ** 2)):.3f} m, iid {np.sqrt(np.mean((J[:, 1] - F[:, 1].mean()) ** 2)):.3f} m; "
              f"intersection line {intersection(line, J[:, 1]):.3f}, iid {intersection(iid, J[:, 1]):.3f}")
        measured.append(J[:, 1]), line_sim.append(line), iid_sim.append(iid)
    m = np.concatenate(measured)
    print(f"both folds pooled ({len(m)} measured): intersection line {intersection(np.concatenate(line_sim), m):.3f}, "
          f"iid {intersection(np.concatenate(iid_sim), m):.3f}")


if __name__ == "__main__":
    main()
