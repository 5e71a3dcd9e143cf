// bench_mpi: one data-parallel training step of the UNet under `mpirun -np N`, split into the
// compute of this rank's share of the global batch and the gradient sum over ranks; the sum
// timed with the algorithm lidar-train uses (train/distributed.h: alltoall + rank-order sum +
// allgather) and with the alternatives it was chosen over. Prints one JSON line on rank 0;
// scripts/bench_mpi.sh runs N = 1, 2 and computes the parallel efficiency.
#include <mpi.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <random>
#include <vector>

#include <cxxopts.hpp>
#include <omp.h>

#include "nn/loss.h"
#include "nn/unet.h"
#include "train/distributed.h"

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}

// The slowest rank sets the pace of a step.
double slowest(double t) {
  double out = t;
  MPI_Allreduce(&t, &out, 1, MPI_DOUBLE, MPI_MAX, MPI_COMM_WORLD);
  return out;
}

void allgather_sum(std::vector<float>& g, int ranks) {
  std::vector<float> all(g.size() * ranks);
  MPI_Allgather(g.data(), static_cast<int>(g.size()), MPI_FLOAT, all.data(), static_cast<int>(g.size()), MPI_FLOAT,
                MPI_COMM_WORLD);
  std::copy(all.begin(), all.begin() + static_cast<std::ptrdiff_t>(g.size()), g.begin());
  for (int r = 1; r < ranks; ++r)
    for (std::size_t i = 0; i < g.size(); ++i) g[i] += all[static_cast<std::size_t>(r) * g.size() + i];
}

void reduce_bcast(std::vector<float>& g, int rank) {
  std::vector<float> sum(g.size());
  MPI_Reduce(g.data(), sum.data(), static_cast<int>(g.size()), MPI_FLOAT, MPI_SUM, 0, MPI_COMM_WORLD);
  if (rank == 0) g = sum;
  MPI_Bcast(g.data(), static_cast<int>(g.size()), MPI_FLOAT, 0, MPI_COMM_WORLD);
}

// Per timed step (the warm-up step excluded): the compute's time and the median time of each way
// to sum the gradients, each on the slowest rank.
struct StepTimes {
  std::vector<double> compute, ours, gather, reduce, builtin;
};

// One data-parallel step on `local` frames per rank, then each gradient sum on its own, after a
// barrier, so the compute's imbalance is not counted.
StepTimes time_steps(lidarsim::nn::UNet& model, int local, int rows, int cols, int batch, int steps, int reps,
                     int rank, int ranks) {
  using namespace lidarsim;
  nn::Tensor x(local, 3, rows, cols), y(local, 1, rows, cols), m(local, 1, rows, cols), pred, d_pred;
  std::mt19937 rng(static_cast<unsigned>(rank + 1));
  std::uniform_real_distribution<float> u(0.f, 1.f);
  for (float& v : x) v = u(rng);
  for (float& v : y) v = u(rng);
  for (float& v : m) v = u(rng) < 0.3f ? 1.f : 0.f;

  train::Distributed& dist = train::Distributed::world();
  const std::size_t params = model.params().size();
  StepTimes out;
  std::vector<float> g(params);
  for (int s = 0; s <= steps; ++s) {  // step 0 warms up
    MPI_Barrier(MPI_COMM_WORLD);
    auto t0 = Clock::now();
    model.params().zero_grads();
    model.forward(x, pred);
    nn::masked_mse(pred, y, m, &d_pred, static_cast<long>(batch) * rows * cols * 3 / 10);
    model.backward(d_pred);
    const double c = slowest(seconds_since(t0));
    std::vector<double> t_ours, t_gather, t_reduce, t_builtin;
    for (int r = 0; r < reps; ++r) {
      auto time = [&](auto&& f) {
        std::copy(model.params().grads(), model.params().grads() + params, g.begin());
        MPI_Barrier(MPI_COMM_WORLD);
        const auto t = Clock::now();
        f();
        return slowest(seconds_since(t));
      };
      t_ours.push_back(time([&] { dist.sum_in_rank_order(g.data(), g.size()); }));
      t_gather.push_back(time([&] { allgather_sum(g, ranks); }));
      t_reduce.push_back(time([&] { reduce_bcast(g, rank); }));
      t_builtin.push_back(time([&] {
        MPI_Allreduce(MPI_IN_PLACE, g.data(), static_cast<int>(g.size()), MPI_FLOAT, MPI_SUM, MPI_COMM_WORLD);
      }));
    }
    if (s == 0) continue;
    out.compute.push_back(c);
    out.ours.push_back(median(t_ours));
    out.gather.push_back(median(t_gather));
    out.reduce.push_back(median(t_reduce));
    out.builtin.push_back(median(t_builtin));
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace lidarsim;
  cxxopts::Options options("bench_mpi", "One data-parallel UNet training step: compute and gradient sum (mpirun -np N)");
  // clang-format off
  options.add_options()
    ("batch", "global batch (frames per step over all ranks)", cxxopts::value<int>()->default_value("2"))
    ("rows", "grid rows", cxxopts::value<int>()->default_value("64"))
    ("cols", "grid columns (a crop of the 1024-column scan)", cxxopts::value<int>()->default_value("512"))
    ("base", "UNet base width", cxxopts::value<int>()->default_value("16"))
    ("depth", "UNet depth", cxxopts::value<int>()->default_value("4"))
    ("threads", "OpenMP threads per rank", cxxopts::value<int>()->default_value("1"))
    ("steps", "timed steps (the median is reported)", cxxopts::value<int>()->default_value("5"))
    ("reps", "timed repetitions of each gradient sum per step", cxxopts::value<int>()->default_value("5"))
    ("h,help", "show this help");
  // clang-format on
  // MPI_Init always here (a singleton without mpirun), so the bench also times N = 1.
  MPI_Init(&argc, &argv);
  const train::Distributed::Session session(&argc, &argv);  // picks up the MPI already running
  int rank = 0, ranks = 1;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank);
  MPI_Comm_size(MPI_COMM_WORLD, &ranks);
  const auto args = options.parse(argc, argv);
  if (args.count("help")) {
    if (rank == 0) std::printf("%s\n", options.help().c_str());
    MPI_Finalize();
    return 0;
  }
  const int batch = args["batch"].as<int>(), rows = args["rows"].as<int>(), cols = args["cols"].as<int>();
  if (batch % ranks != 0) {
    if (rank == 0) std::fprintf(stderr, "error: --batch %d is not a multiple of the %d ranks\n", batch, ranks);
    MPI_Finalize();
    return 2;
  }
  omp_set_num_threads(args["threads"].as<int>());
  const int local = batch / ranks;

  nn::UNet model({3, 1, args["base"].as<int>(), args["depth"].as<int>()});
  model.init(1);
  const std::size_t params = model.params().size();
  const StepTimes t = time_steps(model, local, rows, cols, batch, args["steps"].as<int>(), args["reps"].as<int>(), rank, ranks);
  if (rank == 0) {
    const double flops = 3 * model.forward_flops(local, rows, cols);  // forward + backward (2x)
    std::printf(
        "{\"ranks\": %d, \"threads_per_rank\": %d, \"global_batch\": %d, \"grid\": \"%dx%d\", \"params\": %zu, "
        "\"param_mbytes\": %.3f, \"compute_s\": %.4f, \"gflops_per_rank\": %.2f, \"sum_rank_order_s\": %.5f, "
        "\"allgather_sum_s\": %.5f, \"reduce_bcast_s\": %.5f, \"mpi_allreduce_s\": %.5f, \"step_s\": %.4f}\n",
        ranks, args["threads"].as<int>(), batch, rows, cols, params, params * 4 / 1e6, median(t.compute),
        flops / median(t.compute) / 1e9, median(t.ours), median(t.gather), median(t.reduce), median(t.builtin),
        median(t.compute) + median(t.ours));
  }
  MPI_Finalize();
  return 0;
}
