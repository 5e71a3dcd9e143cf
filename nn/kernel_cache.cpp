#include "nn/kernel_cache.h"

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#if defined(__x86_64__) || defined(__i386__)
#include <cpuid.h>
#endif

#include "common/atomic_file.h"
#include "common/error.h"

namespace lidarsim::nn {

std::string cpu_kind() {
#if defined(__x86_64__) || defined(__i386__)
  unsigned a = 0, b = 0, c = 0, d = 0;
  if (!__get_cpuid(0, &a, &b, &c, &d)) return "unknown";
  char vendor[13] = {};
  std::memcpy(vendor, &b, 4), std::memcpy(vendor + 4, &d, 4), std::memcpy(vendor + 8, &c, 4);
  __get_cpuid(1, &a, &b, &c, &d);
  // The display family and model, as /proc/cpuinfo shows them.
  unsigned family = (a >> 8) & 0xf, model = (a >> 4) & 0xf;
  if (family == 0xf) family += (a >> 20) & 0xff;
  if (family == 0x6 || family >= 0xf) model += ((a >> 16) & 0xf) << 4;
  return std::string(vendor) + "-" + std::to_string(family) + "-" + std::to_string(model);
#else
  return "unknown";
#endif
}

std::string cpu_name() {
#if defined(__x86_64__) || defined(__i386__)
  unsigned r[12] = {};
  for (unsigned i = 0; i < 3; ++i)
    if (!__get_cpuid(0x80000002u + i, &r[4 * i], &r[4 * i + 1], &r[4 * i + 2], &r[4 * i + 3])) return "unknown";
  char text[49] = {};
  std::memcpy(text, r, 48);
  std::string s(text);
  const auto b = s.find_first_not_of(' '), e = s.find_last_not_of(' ');
  return b == std::string::npos ? "unknown" : s.substr(b, e - b + 1);
#else
  return "unknown";
#endif
}

std::filesystem::path kernel_cache_path(Isa isa) {
  std::filesystem::path dir;
  if (const char* d = std::getenv("LIDARSIM_KERNEL_CACHE"); d && *d) {
    dir = d;
  } else if (const char* x = std::getenv("XDG_CACHE_HOME"); x && *x) {
    dir = std::filesystem::path(x) / "lidarsim";
  } else {
    const char* home = std::getenv("HOME");
    dir = std::filesystem::path(home && *home ? home : ".") / ".cache" / "lidarsim";
  }
  return dir / ("kernels-" + cpu_kind() + "-" + to_string(isa) + ".json");
}

std::map<ConvKey, PlanEntry> read_kernel_cache(Isa isa) {
  const std::filesystem::path path = kernel_cache_path(isa);
  std::ifstream in(path);
  if (!in) return {};
  std::stringstream text;
  text << in.rdbuf();
  try {
    const nlohmann::json j = nlohmann::json::parse(text.str());
    if (j.at("kind").get<std::string>() != cpu_kind())
      throw Error(path.string() + ": kind: written for another CPU kind");
    std::map<ConvKey, PlanEntry> out;
    const KernelPlan plan = KernelPlan::from_json(text.str(), path.string());
    for (const auto& [k, e] : plan.entries())
      if (k.isa == isa) out[k] = e;
    return out;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "lidarsim: warning: kernel cache %s is unreadable (%s); measuring again\n", path.c_str(),
                 e.what());
    return {};
  }
}

void write_kernel_cache(Isa isa, const std::map<ConvKey, PlanEntry>& entries) {
  const std::filesystem::path path = kernel_cache_path(isa);
  try {
    KernelPlan plan(PlanMode::calibrated);
    for (const auto& [k, e] : entries)
      if (k.isa == isa) plan.record(k, e);
    nlohmann::json j = nlohmann::json::parse(plan.to_json());
    j["cpu"] = cpu_name();
    j["kind"] = cpu_kind();
    std::filesystem::create_directories(path.parent_path());
    write_file_atomically(path, j.dump(1) + "\n");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "lidarsim: warning: cannot write the kernel cache %s (%s)\n", path.c_str(), e.what());
  }
}

}  // namespace lidarsim::nn
