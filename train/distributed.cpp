#include "train/distributed.h"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "common/error.h"

#ifdef LIDARSIM_WITH_MPI
#include <mpi.h>
#endif

namespace lidarsim::train {

BatchShare batch_share(int batch, int rank, int ranks) {
  const int each = batch / ranks;
  return {rank * each, each};
}

Distributed& Distributed::world() {
  static Distributed instance;
  return instance;
}

#ifdef LIDARSIM_WITH_MPI
namespace {

// Set by the launchers we know (Open MPI, MPICH/Hydra, PMIx as under Slurm's srun): without
// one, the process stays single and never touches MPI, exactly as a build without it.
bool launched_by_mpi() {
  for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK"})
    if (std::getenv(name)) return true;
  return false;
}

bool mpi_running() {
  int initialized = 0, finalized = 0;
  MPI_Initialized(&initialized);
  MPI_Finalized(&finalized);
  return initialized && !finalized;
}

constexpr int kMessageBytes = 1024;

}  // namespace

Distributed::Session::Session(int* argc, char*** argv) {
  if (!mpi_running()) {  // else a caller (bench_mpi) started MPI itself
    if (!launched_by_mpi()) return;
    int provided = 0;
    // OpenMP threads compute; MPI is called from the main thread only.
    MPI_Init_thread(argc, argv, MPI_THREAD_FUNNELED, &provided);
  }
  Distributed& d = world();
  MPI_Comm_rank(MPI_COMM_WORLD, &d.rank_);
  MPI_Comm_size(MPI_COMM_WORLD, &d.size_);
}

Distributed::Session::~Session() {
  if (mpi_running()) MPI_Finalize();
}

void Distributed::sum_in_rank_order(float* data, std::size_t n) {
  if (!active() || n == 0) return;
  // A reduce-scatter done by hand, then an allgather: rank r receives chunk r of every rank
  // (MPI_Alltoall) and adds them in rank order; the summed chunks are then shared. Each rank
  // sends and receives 2 (N-1)/N of the vector, as in a ring allreduce.
  const std::size_t chunk = (n + size_ - 1) / size_;
  const std::size_t padded = chunk * size_;
  if (chunk > static_cast<std::size_t>(INT32_MAX)) throw Error("distributed: vector too long for one exchange");
  std::vector<float> send(padded, 0.f), received(padded), summed(chunk), gathered(padded);
  std::copy(data, data + n, send.begin());
  const int count = static_cast<int>(chunk);
  MPI_Alltoall(send.data(), count, MPI_FLOAT, received.data(), count, MPI_FLOAT, MPI_COMM_WORLD);
  std::copy(received.begin(), received.begin() + count, summed.begin());
  for (int r = 1; r < size_; ++r) {
    const float* part = received.data() + static_cast<std::size_t>(r) * chunk;
    for (std::size_t i = 0; i < chunk; ++i) summed[i] += part[i];
  }
  MPI_Allgather(summed.data(), count, MPI_FLOAT, gathered.data(), count, MPI_FLOAT, MPI_COMM_WORLD);
  std::copy(gathered.begin(), gathered.begin() + static_cast<std::ptrdiff_t>(n), data);
}

void Distributed::sum_in_rank_order(double* data, std::size_t n) {
  if (!active() || n == 0) return;
  // For a handful of values (losses, metrics): gather all, add in rank order.
  std::vector<double> all(n * size_);
  MPI_Allgather(data, static_cast<int>(n), MPI_DOUBLE, all.data(), static_cast<int>(n), MPI_DOUBLE, MPI_COMM_WORLD);
  for (std::size_t i = 0; i < n; ++i) {
    double s = all[i];
    for (int r = 1; r < size_; ++r) s += all[static_cast<std::size_t>(r) * n + i];
    data[i] = s;
  }
}

void Distributed::sum(std::int64_t* data, std::size_t n) {
  if (!active() || n == 0) return;
  MPI_Allreduce(MPI_IN_PLACE, data, static_cast<int>(n), MPI_INT64_T, MPI_SUM, MPI_COMM_WORLD);
}

void Distributed::agree(const std::string& error) {
  if (!active()) {
    if (!error.empty()) throw AgreedError(error);
    return;
  }
  std::int64_t failed = error.empty() ? 0 : 1;
  sum(&failed, 1);
  if (failed == 0) return;
  // Rank 0 collects every rank's message and reports the first failing rank's.
  std::vector<char> mine(kMessageBytes, '\0'), all(root() ? static_cast<std::size_t>(kMessageBytes) * size_ : 1);
  std::strncpy(mine.data(), error.c_str(), kMessageBytes - 1);
  MPI_Gather(mine.data(), kMessageBytes, MPI_CHAR, all.data(), kMessageBytes, MPI_CHAR, 0, MPI_COMM_WORLD);
  if (!root()) throw FailedElsewhere();
  for (int r = 0; r < size_; ++r) {
    const char* text = all.data() + static_cast<std::size_t>(r) * kMessageBytes;
    if (text[0] == '\0') continue;
    std::string message = r == 0 ? text : "rank " + std::to_string(r) + " of " + std::to_string(size_) + ": " + text;
    // The same error everywhere (a bad setting) is one error; different ones are counted.
    for (int other = r + 1; other < size_; ++other) {
      const char* next = all.data() + static_cast<std::size_t>(other) * kMessageBytes;
      if (next[0] != '\0' && std::strcmp(next, text) != 0) {
        message += " (" + std::to_string(failed) + " ranks failed)";
        break;
      }
    }
    throw AgreedError(message);
  }
  throw AgreedError("a rank failed without a message");
}

void Distributed::abort(const std::string& message) {
  std::fprintf(stderr, "error: rank %d of %d: %s\n", rank_, size_, message.c_str());
  std::fflush(stderr);
  if (mpi_running()) MPI_Abort(MPI_COMM_WORLD, 1);
  std::_Exit(1);
}

std::string Distributed::launcher() { return LIDARSIM_MPIEXEC; }

#else  // a build without MPI: always one rank

Distributed::Session::Session(int*, char***) {}
Distributed::Session::~Session() = default;
void Distributed::sum_in_rank_order(float*, std::size_t) {}
void Distributed::sum_in_rank_order(double*, std::size_t) {}
void Distributed::sum(std::int64_t*, std::size_t) {}
void Distributed::agree(const std::string& error) {
  if (!error.empty()) throw AgreedError(error);
}
void Distributed::abort(const std::string& message) {
  std::fprintf(stderr, "error: %s\n", message.c_str());
  std::_Exit(1);
}
std::string Distributed::launcher() { return ""; }

#endif

}  // namespace lidarsim::train
