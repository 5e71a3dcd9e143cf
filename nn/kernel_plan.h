#pragma once
// Which 3x3 kernel each convolution of a model takes, pass by pass: a KernelPlan maps a conv's key
// (pass, shape, active ISA level) to an algorithm. Two ways to fill a miss:
//   rule:       the fixed rules in code (conv3x3_takes_winograd and its kin), measured once on
//               other CPUs; the default for library callers, tests and benches.
//   calibrated: the candidates this CPU has are timed on scratch data of that shape the first time
//               it runs here (nn/kernel_calibration.h), and the result is kept in a cache file per
//               CPU kind and ISA level (nn/kernel_cache.h), so each machine measures once.
// Why a calibration rather than a table keyed by CPU family: a table covers only the CPUs someone
// benched; the calibration covers every CPU a user has.
// Every choice a plan makes is recorded in it; to_json() / from_json() carry it in a checkpoint,
// so a resumed run takes exactly the choices of the run it continues (same bits), whatever the
// cache says by then. A plan belongs to one model and is used by one thread at a time.
#include <compare>
#include <map>
#include <string>
#include <vector>

#include "nn/conv_settings.h"
#include "nn/cpu_features.h"

namespace lidarsim::nn {

// forward, input_grad and weight_grad are the fp32 passes (training and fp32 inference);
// bf16_forward is bf16 inference's forward pass. Below AVX-512 the two gradients share one
// by-phase copy (nn/conv_layers.cpp), so there weight_grad stands for the whole backward pass
// (input_grad only for a backward without a weight gradient).
enum class ConvPass { forward, input_grad, weight_grad, bf16_forward };
// fp32 passes: direct (the AVX-512 direct kernel, or im2col + GEMM below it) or winograd;
// bf16_forward: fp32 (the fp32 forward's own choice), avx512_bf16 or amx.
enum class ConvAlgo { direct, winograd, fp32, avx512_bf16, amx };
enum class PlanMode { rule, calibrated };

const char* to_string(ConvPass p);
const char* to_string(ConvAlgo a);
const char* to_string(PlanMode m);
// "rule" or "calibrated"; anything else throws Error naming `field`.
PlanMode parse_plan_mode(const std::string& text, const std::string& field);

struct ConvKey {
  ConvPass pass = ConvPass::forward;
  int n = 0, ci = 0, co = 0, h = 0, w = 0;  // the conv's own ci -> co, whatever the pass
  Isa isa = Isa::avx2;
  auto operator<=>(const ConvKey&) const = default;
};

struct PlanEntry {
  ConvAlgo algo = ConvAlgo::direct;
  std::map<std::string, double> seconds;  // calibrated: each candidate's minimum time; empty under the rule
  bool operator==(const PlanEntry&) const = default;
};

// Today's fixed rule for `key` under `path` (a forced path wins, as it always has).
ConvAlgo rule_choice(const ConvKey& key, detail::Conv3x3Path path = detail::Conv3x3Path::automatic);
// The algorithms `key`'s pass has on this CPU at key.isa, the rule's choice first.
std::vector<ConvAlgo> candidates(const ConvKey& key);

class KernelPlan {
 public:
  explicit KernelPlan(PlanMode mode = PlanMode::rule) : mode_(mode) {}
  PlanMode mode() const { return mode_; }

  // The recorded choice for `key`; on a miss, the mode's (calibrated: the cache file's, else
  // measured now and written to it), recorded from then on.
  ConvAlgo lookup(const ConvKey& key);
  // Records `algo` for `key` (tests force a non-rule choice; checks that the pass can take it).
  void set(const ConvKey& key, ConvAlgo algo);
  void record(const ConvKey& key, const PlanEntry& entry) { entries_[key] = entry; }
  const std::map<ConvKey, PlanEntry>& entries() const { return entries_; }
  // Wall time this plan spent measuring (callers that time their own work leave it out).
  double calibration_seconds() const { return calibration_seconds_; }

  // {"mode": ..., "choices": [{"pass", "n", "ci", "co", "h", "w", "isa", "algo", "seconds"}...]}.
  std::string to_json() const;
  // The plan of to_json(); a bad field throws Error naming `where` and the field.
  static KernelPlan from_json(const std::string& json, const std::string& where);
  // One line per choice, for logs: "forward n1 3->16 64x1024 avx512: direct (direct 1.2 ms, winograd 1.5 ms)".
  std::string describe() const;

 private:
  PlanMode mode_;
  std::map<ConvKey, PlanEntry> entries_;
  std::map<Isa, std::map<ConvKey, PlanEntry>> disk_;  // the cache files read so far, per ISA level
  bool announced_ = false;                            // the stderr line of the first calibration
  double calibration_seconds_ = 0;
};

namespace detail {
// The algorithm a conv op takes for one pass: a forced cs.conv3x3 or no plan give the rule;
// else the plan's choice at the active ISA level. Call before touching per-thread scratch: a
// calibration runs the kernels themselves.
ConvAlgo conv_choice(const ConvSettings& cs, ConvPass pass, int n, int ci, int co, int h, int w);
}  // namespace detail

}  // namespace lidarsim::nn
