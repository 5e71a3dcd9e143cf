#pragma once
// Times the candidate kernels of one conv key on scratch data of its shape (nn/kernel_plan.h):
// one warm-up each, then kTimedRuns timed runs each, the candidates alternating so that a change
// of load or clock touches them all alike, and each one's minimum kept (the noise of a shared
// machine only ever adds time). The fastest wins unless the rule's choice is within kTieMargin.
#include "nn/kernel_plan.h"

namespace lidarsim::nn {

constexpr int kTimedRuns = 3;
constexpr double kTieMargin = 0.03;

// Measures key's candidates (candidates(key)) at the active ISA level, which must be key.isa.
// fp32_forward: what the bf16 pass's fp32 candidate runs (the plan's forward choice).
PlanEntry calibrate(const ConvKey& key, ConvAlgo fp32_forward);

namespace testhook {
// How many calibrations (one per key) ran in this process: lets a test see a cache hit.
long calibrations();
}  // namespace testhook

}  // namespace lidarsim::nn
