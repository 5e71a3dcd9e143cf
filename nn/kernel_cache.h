#pragma once
// The calibrated kernel plans' cache on disk (nn/kernel_plan.h): one JSON file per CPU kind and
// ISA level, $LIDARSIM_KERNEL_CACHE/kernels-<kind>-<isa>.json when that variable is set, else
// ${XDG_CACHE_HOME:-$HOME/.cache}/lidarsim/kernels-<kind>-<isa>.json. The file is a plan's JSON
// plus "cpu" (the CPU's name) and "kind"; written whole to a temporary and renamed, so readers
// never see a torn file. A file that does not parse is a one-line warning naming it and is
// measured again (and rewritten), never an error.
#include <filesystem>
#include <map>
#include <string>

#include "nn/kernel_plan.h"

namespace lidarsim::nn {

// "<vendor>-<family>-<model>" from CPUID (e.g. "GenuineIntel-6-143"), "unknown" elsewhere.
std::string cpu_kind();
// The CPU's brand string (CPUID), or "unknown".
std::string cpu_name();

std::filesystem::path kernel_cache_path(Isa isa);

// The choices in the cache file for `isa` (empty when there is none; warns and returns empty
// when it is corrupt or belongs to another CPU kind or level).
std::map<ConvKey, PlanEntry> read_kernel_cache(Isa isa);
// Writes `entries` (those at `isa`) as the cache file for `isa`; a failure is a one-line warning
// (the run goes on with its choices; the next one measures again).
void write_kernel_cache(Isa isa, const std::map<ConvKey, PlanEntry>& entries);

}  // namespace lidarsim::nn
