// Soak run of the OSMP FMU (issue 29, item 5): --minutes of simulated time at --rate Hz through
// lidarsim_osi.fmu as an importer drives it (unzip, dlopen, fmi2Instantiate, set the SensorView
// pointer integers, fmi2DoStep, read the SensorData pointer), in this process. The scene never
// ends: the host drives at 10 m/s along x, --objects cars and crossing pedestrians stay in a window
// around it (wrapping round when they leave it, so tracks end and start all the time), and two lane
// boundaries follow it. For each simulated minute it prints the step time (set + DoStep + get;
// building and serializing the SensorView is the importer's and not counted) median and p99 and the
// process's resident memory at the end of the minute; the summary compares the first and the last
// minute. Memory or time that grows with the run shows there.
#include <dlfcn.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cxxopts.hpp>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "bench/osi_bench_scene.h"
#include "infer/fmu/fmi2.h"
#include "osi/osi3_subset.pb.h"
#include "osi/sensor_view.h"

namespace fs = std::filesystem;

namespace {

[[noreturn]] void die(const std::string& what) {
  std::fprintf(stderr, "bench_osi_soak: %s\n", what.c_str());
  std::exit(1);
}

long rss_kib() {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("VmRSS:", 0) == 0) return std::stol(line.substr(6));
  return -1;
}

struct Window {
  double median = 0, p99 = 0;
};
Window window(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return {v[v.size() / 2], v[std::min(v.size() - 1, v.size() * 99 / 100)]};
}

struct Mover {
  double x0, y0, vx, vy;
  bool ped;
};

// Wraps v into [lo, lo + span).
double wrap(double v, double lo, double span) { return lo + std::fmod(std::fmod(v - lo, span) + span, span); }

void make_view(const std::vector<Mover>& movers, double t, osi3::SensorView& v) {
  v.Clear();
  lidarsim::osi::set_timestamp(t, *v.mutable_timestamp());
  v.mutable_sensor_id()->set_value(1);
  v.mutable_host_vehicle_id()->set_value(1000);
  v.mutable_mounting_position()->mutable_position()->set_x(1.4);
  v.mutable_mounting_position()->mutable_position()->set_z(1.43);
  auto& gt = *v.mutable_global_ground_truth();
  auto add = [&](std::uint64_t id, bool ped, double x, double y, double vx, double vy) {
    return lidarsim::bench::add_bench_object(gt, id, ped, x, y, vx, vy);
  };
  const double host_x = 10 * t;
  auto* host = add(1000, false, host_x + 1.4, 0, 10, 0);
  host->mutable_vehicle_attributes()->mutable_bbcenter_to_rear()->set_x(-1.4);
  host->mutable_vehicle_attributes()->mutable_bbcenter_to_rear()->set_z(-0.45);
  for (std::size_t i = 0; i < movers.size(); ++i) {
    const Mover& m = movers[i];
    double rx = wrap(m.x0 + (m.vx - 10) * t, -30, 90);
    const double y = m.ped ? wrap(m.y0 + m.vy * t, -20, 40) : m.y0;
    if (std::abs(y) < 3 && std::abs(rx) < 8) rx += 16;  // never on top of the host
    add(i + 1, m.ped, host_x + rx, y, m.vx, m.vy);
  }
  const double x_start = 10 * std::floor((host_x - 50) / 10);
  for (int side : {-1, 1}) {
    auto* l = gt.add_lane_boundary();
    l->mutable_id()->set_value(side < 0 ? 2001 : 2002);
    l->mutable_classification()->set_type(osi3::LaneBoundary::Classification::TYPE_SOLID_LINE);
    for (double x = x_start; x <= x_start + 250; x += 10) {
      auto* p = l->add_boundary_line()->mutable_position();
      p->set_x(x);
      p->set_y(side * 1.75);
    }
  }
}

std::string attribute(const std::string& xml, const std::string& name) {
  const auto at = xml.find(" " + name + "=\"");
  if (at == std::string::npos) die("modelDescription.xml has no " + name);
  const auto start = at + name.size() + 3;
  return xml.substr(start, xml.find('"', start) - start);
}

template <typename F>
F* symbol(void* lib, const char* name) {
  auto* f = reinterpret_cast<F*>(dlsym(lib, name));
  if (!f) die(std::string("the FMU does not export ") + name);
  return f;
}

void logger(fmi2ComponentEnvironment, fmi2String, fmi2Status status, fmi2String category, fmi2String message, ...) {
  if (status >= fmi2Warning) std::fprintf(stderr, "fmu %s: %s\n", category, message);
}

}  // namespace

int main(int argc, char** argv) {
  cxxopts::Options opts("bench_osi_soak", "a long run of the OSMP FMU: step time and memory per simulated minute");
  opts.add_options()
    ("fmu", "the FMU", cxxopts::value<std::string>()->default_value("build/lidarsim_osi.fmu"))
    ("minutes", "simulated minutes", cxxopts::value<double>()->default_value("30"))
    ("rate", "frames per simulated second (the FMU's step is 1/rate)", cxxopts::value<double>()->default_value("10"))
    ("objects", "moving objects besides the host", cxxopts::value<int>()->default_value("20"))
    ("h,help", "this text");
  const auto args = opts.parse(argc, argv);
  if (args.count("help")) {
    std::printf("%s\n", opts.help().c_str());
    return 0;
  }
  const double minutes = args["minutes"].as<double>(), rate = args["rate"].as<double>();
  const int objects = args["objects"].as<int>();
  if (!(minutes > 0) || !(rate > 0) || objects < 0) die("--minutes and --rate must be positive, --objects >= 0");
  const fs::path fmu = fs::absolute(args["fmu"].as<std::string>());
  if (!fs::exists(fmu)) die(fmu.string() + ": no such file (build lidarsim_osi_fmu_package)");

  char tmpl[] = "/tmp/bench_osi_soak.XXXXXX";
  if (!mkdtemp(tmpl)) die("cannot make a temporary folder");
  const fs::path dir = tmpl;
  if (std::system(("cd " + dir.string() + " && cmake -E tar xf " + fmu.string()).c_str()) != 0)
    die(fmu.string() + ": cannot be unpacked");
  std::ifstream xml_file(dir / "modelDescription.xml");
  std::stringstream xml;
  xml << xml_file.rdbuf();
  const std::string guid = attribute(xml.str(), "guid"), id = attribute(xml.str(), "modelIdentifier");
  void* lib = dlopen((dir / "binaries" / "linux64" / (id + ".so")).c_str(), RTLD_NOW | RTLD_LOCAL);
  if (!lib) die(std::string("dlopen: ") + dlerror());
  auto* instantiate = symbol<fmi2InstantiateTYPE>(lib, "fmi2Instantiate");
  auto* setup = symbol<fmi2SetupExperimentTYPE>(lib, "fmi2SetupExperiment");
  auto* enter = symbol<fmi2EnterInitializationModeTYPE>(lib, "fmi2EnterInitializationMode");
  auto* exit_init = symbol<fmi2ExitInitializationModeTYPE>(lib, "fmi2ExitInitializationMode");
  auto* set_int = symbol<fmi2SetIntegerTYPE>(lib, "fmi2SetInteger");
  auto* get_int = symbol<fmi2GetIntegerTYPE>(lib, "fmi2GetInteger");
  auto* do_step = symbol<fmi2DoStepTYPE>(lib, "fmi2DoStep");
  auto* terminate = symbol<fmi2TerminateTYPE>(lib, "fmi2Terminate");
  auto* free_instance = symbol<fmi2FreeInstanceTYPE>(lib, "fmi2FreeInstance");

  fmi2CallbackFunctions callbacks{};
  callbacks.logger = logger;
  const std::string resources = "file://" + (dir / "resources").string();
  fmi2Component c = instantiate("soak", fmi2CoSimulation, guid.c_str(), resources.c_str(), &callbacks, 0, 0);
  if (!c) die("fmi2Instantiate failed");
  if (setup(c, 0, 0, 0, 0, 0) != fmi2OK || enter(c) != fmi2OK || exit_init(c) != fmi2OK) die("initialisation failed");

  std::mt19937 rng(3);
  std::uniform_real_distribution<double> ux(-30, 60), uy(-20, 20), uv(8, 14);
  std::vector<Mover> movers;
  for (int i = 0; i < objects; ++i) {
    const bool ped = i % 5 == 4;
    const double y = uy(rng);
    movers.push_back({ux(rng), y, ped ? 10.0 : uv(rng), ped ? (y > 0 ? -1.4 : 1.4) : 0.0, ped});
  }

  const long frames = std::lround(minutes * 60 * rate);
  const long per_minute = std::max(1L, std::lround(60 * rate));
  const fmi2ValueReference in_vr[3] = {0, 1, 2}, out_vr[3] = {3, 4, 5};
  osi3::SensorView view;
  std::string bytes;
  std::vector<double> ms;
  Window first{}, last{};
  long rss_first = 0, rss_last = 0, detections = 0;
  std::printf("| simulated minute | frames | step median (ms) | step p99 (ms) | RSS (MiB) |\n|---:|---:|---:|---:|---:|\n");
  for (long k = 0; k < frames; ++k) {
    const double t = static_cast<double>(k) / rate;
    make_view(movers, t, view);
    view.SerializeToString(&bytes);
    const auto address = reinterpret_cast<std::uintptr_t>(bytes.data());
    const fmi2Integer in[3] = {static_cast<fmi2Integer>(static_cast<std::uint32_t>(address & 0xffffffffu)),
                               static_cast<fmi2Integer>(static_cast<std::uint32_t>(std::uint64_t(address) >> 32)),
                               static_cast<fmi2Integer>(bytes.size())};
    fmi2Integer out[3] = {0, 0, 0};
    const auto start = std::chrono::steady_clock::now();
    if (set_int(c, in_vr, 3, in) != fmi2OK) die("fmi2SetInteger failed at frame " + std::to_string(k));
    if (do_step(c, t, 1 / rate, 1) != fmi2OK) die("fmi2DoStep failed at frame " + std::to_string(k));
    if (get_int(c, out_vr, 3, out) != fmi2OK || out[2] <= 0) die("no SensorData at frame " + std::to_string(k));
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
    if (k == frames - 1) {  // the last output, decoded once to show it is whole
      const auto out_address = static_cast<std::uintptr_t>(static_cast<std::uint32_t>(out[0])) |
                               static_cast<std::uintptr_t>(static_cast<std::uint32_t>(out[1])) << 32;
      osi3::SensorData data;
      if (!data.ParseFromArray(reinterpret_cast<const void*>(out_address), out[2])) die("the last SensorData does not parse");
      if (data.feature_data().lidar_sensor_size() > 0) detections = data.feature_data().lidar_sensor(0).detection_size();
    }
    if (static_cast<long>(ms.size()) == per_minute || k == frames - 1) {
      const Window w = window(ms);
      const long rss = rss_kib();
      std::printf("| %ld | %zu | %.1f | %.1f | %.1f |\n", (k + 1 + per_minute - 1) / per_minute, ms.size(), w.median,
                  w.p99, rss / 1024.0);
      std::fflush(stdout);
      if (k < per_minute) {
        first = w;
        rss_first = rss;
      }
      last = w;
      rss_last = rss;
      ms.clear();
    }
  }
  std::printf("\n%ld frames (%.1f simulated minutes at %.0f Hz, %d objects, %ld lidar detections in the last frame)\n",
              frames, minutes, rate, objects, detections);
  std::printf("first minute: median %.1f ms, p99 %.1f ms, RSS %.1f MiB; last minute: median %.1f ms, p99 %.1f ms, RSS %.1f MiB\n",
              first.median, first.p99, rss_first / 1024.0, last.median, last.p99, rss_last / 1024.0);
  terminate(c);
  free_instance(c);
  dlclose(lib);
  fs::remove_all(dir);
  return 0;
}
