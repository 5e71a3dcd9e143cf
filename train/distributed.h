#pragma once
// The processes that train one model together: MPI ranks under `mpirun -np N lidar-train`, or one
// process. The only file of train/ that knows MPI (distributed.cpp); a build without MPI
// (-DLIDARSIM_MPI=OFF, or no MPI installed) gets the single-rank implementation.
//
// Every call here is collective: all ranks make the same calls in the same order. Sums of floats
// run in a fixed order (rank 0 + rank 1 + ... + rank N-1 for every element), so for a fixed N a
// run gives the same bits every time, whatever algorithm the MPI library would have picked.
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>

#include "common/error.h"

namespace lidarsim::train {

// Which samples of a global batch a rank trains on: slots [begin, begin + count).
struct BatchShare {
  int begin = 0, count = 0;
};
// Consecutive equal shares; the batch must be a multiple of the rank count (validate_settings).
BatchShare batch_share(int batch, int rank, int ranks);

// What agree() throws once every rank knows of a failure: on rank 0 the message to report, on
// the others FailedElsewhere (they exit non-zero without a message of their own).
struct AgreedError : Error {
  using Error::Error;
};
struct FailedElsewhere : AgreedError {
  FailedElsewhere() : AgreedError("failed on another rank; rank 0 reports it") {}
};

class Distributed {
 public:
  // MPI_Init when the process was started by an MPI launcher (mpirun, srun); otherwise nothing,
  // and the process is rank 0 of 1. The returned guard finalizes MPI when it goes out of scope.
  struct Session {
    Session(int* argc, char*** argv);
    ~Session();
    Session(const Session&) = delete;
    Session& operator=(const Session&) = delete;
  };

  static Distributed& world();
  int rank() const { return rank_; }
  int size() const { return size_; }
  bool root() const { return rank_ == 0; }
  bool active() const { return size_ > 1; }

  // data[i] = sum over ranks of data[i], added in rank order; the same bits on every rank.
  void sum_in_rank_order(float* data, std::size_t n);
  void sum_in_rank_order(double* data, std::size_t n);
  // Exact integer sums (order does not matter).
  void sum(std::int64_t* data, std::size_t n);

  // Every rank passes its own error ("" when fine). When any rank failed, rank 0 throws an Error
  // with the message of the lowest failing rank ("rank 1 of 2: ..."), the others FailedElsewhere.
  // One rank alone throws its own error unchanged.
  void agree(const std::string& error);

  // Ends every process of the job at once (MPI_Abort) after printing `message` on this rank; for
  // errors outside the agreed points, where the other ranks would otherwise wait forever.
  [[noreturn]] void abort(const std::string& message);

  // The MPI launcher this build was made with (e.g. /usr/bin/mpiexec); "" in a build without MPI.
  static std::string launcher();

 private:
  Distributed() = default;
  int rank_ = 0, size_ = 1;
};

}  // namespace lidarsim::train
