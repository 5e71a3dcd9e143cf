// Per-frame latency of `lidar-infer osi` on a stream (issue 14): a co-simulation writes one
// osi3.SensorView (host + --objects moving objects, lane boundaries) to the command's stdin and
// waits for its osi3.SensorData on stdout, frame after frame. Reported: the round trip per frame
// (write the SensorView -> the whole SensorData read back), and as the peer in the same run the
// same frames through OsiRunner in this process (parse, model, serialize: no pipes, no second
// process). Median and p95 over --frames after --warmup frames; the load average is printed
// because the number depends on what else the machine runs.
#include <omp.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <cxxopts.hpp>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "bench/osi_bench_scene.h"
#include "common/error.h"
#include "infer/osi_runner.h"
#include "osi/osi3_subset.pb.h"
#include "osi/sensor_data.h"
#include "osi/sensor_view.h"

using namespace lidarsim;
namespace fs = std::filesystem;

namespace {

struct Stats {
  double median = 0, p95 = 0;
};

Stats stats(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return {v[v.size() / 2], v[std::min(v.size() - 1, v.size() * 95 / 100)]};
}

// Host driving at 10 m/s along x; objects on both sides and ahead, 80 % cars at 8-14 m/s along
// the road, 20 % pedestrians crossing at 1.4 m/s; two solid lane boundaries.
std::vector<std::string> make_frames(int frames, int objects) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> ux(-30, 60), uy(-20, 20), uv(8, 14);
  struct O {
    double x, y, vx, vy;
    bool ped;
  };
  std::vector<O> os;
  for (int i = 0; i < objects; ++i) {
    const bool ped = i % 5 == 4;
    double x = ux(rng), y = uy(rng);
    if (std::abs(y) < 3 && std::abs(x) < 8) y += 6;  // not on top of the host
    os.push_back({x, y, ped ? 10.0 : uv(rng), ped ? (y > 0 ? -1.4 : 1.4) : 0.0, ped});
  }
  std::vector<std::string> out;
  for (int k = 0; k < frames; ++k) {
    const double t = 0.1 * k;
    osi3::SensorView v;
    osi::set_timestamp(t, *v.mutable_timestamp());
    v.mutable_sensor_id()->set_value(1);
    v.mutable_host_vehicle_id()->set_value(1000);
    v.mutable_mounting_position()->mutable_position()->set_x(1.4);
    v.mutable_mounting_position()->mutable_position()->set_z(1.43);
    auto& gt = *v.mutable_global_ground_truth();
    auto add = [&](std::uint64_t id, bool ped, double x, double y, double vx, double vy) {
      return lidarsim::bench::add_bench_object(gt, id, ped, x, y, vx, vy);
    };
    auto* host = add(1000, false, 10 * t + 1.4, 0, 10, 0);
    host->mutable_vehicle_attributes()->mutable_bbcenter_to_rear()->set_x(-1.4);
    host->mutable_vehicle_attributes()->mutable_bbcenter_to_rear()->set_z(-0.45);
    for (std::size_t i = 0; i < os.size(); ++i)
      add(i + 1, os[i].ped, os[i].x + os[i].vx * t, os[i].y + os[i].vy * t, os[i].vx, os[i].vy);
    for (int side : {-1, 1}) {
      auto* l = gt.add_lane_boundary();
      l->mutable_id()->set_value(side < 0 ? 2001 : 2002);
      l->mutable_classification()->set_type(osi3::LaneBoundary::Classification::TYPE_SOLID_LINE);
      for (double x = -50; x <= 200; x += 10) {
        auto* p = l->add_boundary_line()->mutable_position();
        p->set_x(x);
        p->set_y(side * 1.75);
      }
    }
    out.push_back(v.SerializeAsString());
  }
  return out;
}

void write_all(int fd, const char* p, std::size_t n) {
  while (n > 0) {
    const ssize_t w = ::write(fd, p, n);
    if (w <= 0) throw Error("bench: write to lidar-infer failed");
    p += w;
    n -= static_cast<std::size_t>(w);
  }
}

void read_all(int fd, char* p, std::size_t n) {
  while (n > 0) {
    const ssize_t r = ::read(fd, p, n);
    if (r <= 0) throw Error("bench: lidar-infer closed its output early");
    p += r;
    n -= static_cast<std::size_t>(r);
  }
}

}  // namespace

int main(int argc, char** argv) {
  cxxopts::Options options("bench_osi_stream", "Per-frame latency of lidar-infer osi on stdin/stdout");
  // clang-format off
  options.add_options()
    ("frames", "measured frames", cxxopts::value<int>()->default_value("40"))
    ("warmup", "frames before measuring (tracks confirm, buffers grow)", cxxopts::value<int>()->default_value("5"))
    ("objects", "moving objects besides the host", cxxopts::value<int>()->default_value("100"))
    ("threads", "OpenMP threads (both runs)", cxxopts::value<int>()->default_value("2"))
    ("no-point-cloud", "object-level model only (both runs)")
    ("exe", "lidar-infer", cxxopts::value<std::string>()->default_value(""))
    ("h,help", "help");
  // clang-format on
  const auto args = options.parse(argc, argv);
  if (args.count("help")) {
    std::printf("%s\n", options.help().c_str());
    return 0;
  }
  try {
    const int frames = args["frames"].as<int>(), warmup = args["warmup"].as<int>();
    const int threads = args["threads"].as<int>();
    const std::string src = LIDARSIM_SOURCE_DIR;
    fs::path exe = args["exe"].as<std::string>();
    if (exe.empty()) exe = fs::canonical("/proc/self/exe").parent_path().parent_path() / "infer" / "lidar-infer";
    const auto msgs = make_frames(warmup + frames, args["objects"].as<int>());
    using clock = std::chrono::steady_clock;
    auto ms = [](clock::time_point a, clock::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); };

    // Peer: the same frames in this process.
    omp_set_num_threads(threads);
    const bool objects_only = args.count("no-point-cloud") > 0;
    infer::SimOptions sim;
    if (objects_only) sim.point_cloud = sim.intensity = false;
    auto runner = infer::OsiRunner::from_files(src + "/data/scenarios/demo_urban.json",
                                               src + "/data/models/kpi_pointrcnn.json",
                                               src + "/data/models/intensity_unet.h5", sim);
    std::vector<double> local;
    osi3::SensorView view;
    osi3::SensorData data;
    std::string bytes;
    std::size_t objects_out = 0, points_out = 0;
    for (std::size_t k = 0; k < msgs.size(); ++k) {
      const auto t0 = clock::now();
      view.ParseFromString(msgs[k]);
      runner.step(view, static_cast<long>(k), "bench", data);
      data.SerializeToString(&bytes);
      if (static_cast<int>(k) >= warmup) {
        local.push_back(ms(t0, clock::now()));
        objects_out += static_cast<std::size_t>(data.moving_object_size());
        if (data.feature_data().lidar_sensor_size() > 0)
          points_out += static_cast<std::size_t>(data.feature_data().lidar_sensor(0).detection_size());
      }
    }

    // The stream: lidar-infer osi --in - --out - as a child process.
    int to_child[2], from_child[2];
    if (pipe(to_child) || pipe(from_child)) throw Error("bench: pipe failed");
    const pid_t pid = fork();
    if (pid == 0) {
      dup2(to_child[0], 0);
      dup2(from_child[1], 1);
      close(to_child[1]);
      close(from_child[0]);
      const std::string t = std::to_string(threads);
      if (objects_only)
        execl(exe.c_str(), exe.c_str(), "osi", "--in", "-", "--out", "-", "--threads", t.c_str(), "--quiet",
              "--no-point-cloud", static_cast<char*>(nullptr));
      else
        execl(exe.c_str(), exe.c_str(), "osi", "--in", "-", "--out", "-", "--threads", t.c_str(), "--quiet",
              static_cast<char*>(nullptr));
      std::perror("exec lidar-infer");
      _exit(127);
    }
    close(to_child[0]);
    close(from_child[1]);
    std::vector<double> stream;
    std::string reply;
    for (std::size_t k = 0; k < msgs.size(); ++k) {
      const auto n = static_cast<std::uint32_t>(msgs[k].size());
      const char header[4] = {static_cast<char>(n), static_cast<char>(n >> 8), static_cast<char>(n >> 16),
                              static_cast<char>(n >> 24)};
      const auto t0 = clock::now();
      write_all(to_child[1], header, 4);
      write_all(to_child[1], msgs[k].data(), msgs[k].size());
      unsigned char len[4];
      read_all(from_child[0], reinterpret_cast<char*>(len), 4);
      reply.resize(len[0] | len[1] << 8 | len[2] << 16 | static_cast<std::uint32_t>(len[3]) << 24);
      read_all(from_child[0], reply.data(), reply.size());
      if (static_cast<int>(k) >= warmup) stream.push_back(ms(t0, clock::now()));
    }
    close(to_child[1]);
    int status = 0;
    waitpid(pid, &status, 0);
    close(from_child[0]);
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) throw Error("bench: lidar-infer osi failed");

    double load[3] = {0, 0, 0};
    if (std::FILE* f = std::fopen("/proc/loadavg", "r")) {
      if (std::fscanf(f, "%lf %lf %lf", &load[0], &load[1], &load[2]) != 3) load[0] = -1;
      std::fclose(f);
    }
    const Stats a = stats(stream), b = stats(local);
    std::printf("lidar-infer osi%s on a pipe, %d objects, %d threads, %d frames after %d warm-up "
                "(%.0f reported objects, %.0f lidar detections per frame):\n",
                objects_only ? " --no-point-cloud" : "", args["objects"].as<int>(), threads, frames, warmup, double(objects_out) / frames,
                double(points_out) / frames);
    std::printf("  stream round trip (SensorView written -> SensorData read): median %.1f ms, p95 %.1f ms\n", a.median, a.p95);
    std::printf("  in-process peer (parse, model, serialize):                 median %.1f ms, p95 %.1f ms\n", b.median, b.p95);
    std::printf("  ratio stream / in-process (median): %.2f; load average %.2f %.2f %.2f on %ld cores\n",
                a.median / b.median, load[0], load[1], load[2], sysconf(_SC_NPROCESSORS_ONLN));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
  return 0;
}
