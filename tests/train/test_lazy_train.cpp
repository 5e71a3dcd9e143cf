// Lazy training: frames read per step from the file with a prefetching thread give the
// run that training on the dataset in memory gives, bit for bit; files in the first dataset layout train too; a damaged
// frame is named; the prefetcher stops on Ctrl-C; memory does not grow with the frame count.
#include <gtest/gtest.h>
#include <hdf5.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <string>

#include "common/error.h"
#include "data/baselines.h"
#include "data/dataset.h"
#include "data/dataset_writer.h"
#include "data/frame_source.h"
#include "tests/data/temp_dir.h"
#include "tests/support/file_bytes.h"
#include "tests/support/sanitizer.h"
#include "train/frame_batches.h"
#include "train/trainer.h"

using lidarsim::testing::read_bytes;

namespace fs = std::filesystem;
using namespace lidarsim;
using lidarsim::testing::TempDir;

namespace {

// Streams `frames` synthetic frames (range, class, material; intensity depends on class and range)
// to `path`, one at a time, as an import does.
void write_synthetic(const fs::path& path, int frames, int rows, int cols) {
  const auto layout = pgm::BeamLayout::uniform(rows, 2.0, -24.0, cols);
  data::DatasetWriter writer(path, {"range", "class", "material"}, layout, "synthetic", false);
  const std::size_t plane = static_cast<std::size_t>(rows) * cols;
  std::vector<float> pgm(3 * plane), target(plane), mask(plane);
  for (int f = 0; f < frames; ++f) {
    for (int r = 0; r < rows; ++r)
      for (int c = 0; c < cols; ++c) {
        const std::size_t i = static_cast<std::size_t>(r) * cols + c;
        const bool hit = (r * 7 + c * 3 + f) % 5 != 0;
        const float range = 4.f + 3.f * r + 8.f * std::sin(0.1f * c + f);
        const int cls = (c / 8) % 2 ? pgm::cls::road : pgm::cls::car;
        pgm[i] = hit ? range : 0.f;
        pgm[plane + i] = hit ? static_cast<float>(cls) : 0.f;
        pgm[2 * plane + i] = hit ? static_cast<float>(pgm::default_material(cls)) : 0.f;
        target[i] = hit ? (cls == pgm::cls::car ? 0.6f : 0.2f) - range / 200.f : 0.f;
        mask[i] = hit ? 1.f : 0.f;
      }
    const std::string id = "synthetic/00/" + std::to_string(f);
    writer.append(pgm.data(), target.data(), mask.data(), nullptr, id, "ring", {"synthetic", "00", std::to_string(f)});
  }
  writer.commit();
}

train::TrainConfig small_config(const fs::path& data, const fs::path& out) {
  train::TrainConfig c;
  c.data = {data};
  c.base = 4;
  c.depth = 2;
  c.epochs = 3;
  c.steps_per_epoch = 4;
  c.batch = 2;
  c.crop_columns = 32;
  c.lr = 3e-3f;
  c.seed = 5;
  c.threads = 2;
  c.out = out;
  c.progress = false;
  c.split = "interleaved";  // 64 columns cannot hold guard bands; these tests are about reading
  c.cache_mb = 0;           // every step reads its frames from the file
  return c;
}

bool same_weights(const train::TrainResult& a, const train::TrainResult& b) {
  const auto& pa = a.model->params();
  const auto& pb = b.model->params();
  return pa.size() == pb.size() && std::memcmp(pa.values(), pb.values(), pa.size() * sizeof(float)) == 0;
}

void expect_same_epochs(const train::TrainResult& a, const train::TrainResult& b) {
  ASSERT_EQ(a.epochs.size(), b.epochs.size());
  for (std::size_t e = 0; e < a.epochs.size(); ++e) {
    EXPECT_EQ(a.epochs[e].train_loss, b.epochs[e].train_loss) << "epoch " << e + 1;
    EXPECT_EQ(a.epochs[e].validation.mae, b.epochs[e].validation.mae) << "epoch " << e + 1;
    EXPECT_EQ(a.epochs[e].validation.cells, b.epochs[e].validation.cells) << "epoch " << e + 1;
  }
}

long status_kb(const char* field) {
  std::ifstream in("/proc/self/status");
  for (std::string line; std::getline(in, line);)
    if (line.rfind(field, 0) == 0) return std::stol(line.substr(std::strlen(field)));
  return -1;
}

int thread_count() {
  int n = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator("/proc/self/task")) ++n;
  return n;
}

}  // namespace

TEST(LazyTrain, FramesReadPerStepGiveTheInMemoryRunBitForBit) {
  TempDir dir;
  write_synthetic(dir / "d.h5", 5, 16, 64);
  train::TrainConfig c = small_config(dir / "d.h5", dir / "lazy.h5");
  const auto lazy = train::train(c);  // reads frames from the file per step
  c.out = dir / "eager.h5";
  const data::Dataset all = data::read_dataset(dir / "d.h5");
  const auto eager = train::train_on(c, {&all}, {"d.h5"});
  expect_same_epochs(lazy, eager);
  EXPECT_TRUE(same_weights(lazy, eager));
  // Everything the checkpoint records but the output name is the same too.
  EXPECT_EQ(read_bytes(dir / "lazy.h5").size(), read_bytes(dir / "eager.h5").size());
  ASSERT_EQ(lazy.epochs.size(), 3u);
  EXPECT_GT(lazy.epochs[0].validation.cells, 0);
}

TEST(LazyTrain, PrefetchingThreadAndSynchronousReadsGiveTheSameRunWithASeparateValidationSet) {
  TempDir dir;
  write_synthetic(dir / "d.h5", 4, 16, 64);
  write_synthetic(dir / "v.h5", 2, 16, 64);
  train::TrainConfig c = small_config(dir / "d.h5", dir / "a.h5");
  c.validation = dir / "v.h5";
  c.crop_columns = 0;  // whole scans, rolled and mirrored
  const auto background = train::train(c);
  c.prefetch = false;
  c.out = dir / "b.h5";
  const auto synchronous = train::train(c);
  c.prefetch = true;
  c.cache_mb = 64;  // every frame read once, then from memory
  c.out = dir / "c.h5";
  const auto cached = train::train(c);
  expect_same_epochs(background, synchronous);
  expect_same_epochs(background, cached);
  EXPECT_TRUE(same_weights(background, synchronous));
  EXPECT_TRUE(same_weights(background, cached));
  EXPECT_EQ(read_bytes(dir / "a.h5"), read_bytes(dir / "b.h5"));
}

TEST(LazyTrain, StreamingValidationScoresExactlyAsEvaluatePredictionOnTheSetInMemory) {
  TempDir dir;
  write_synthetic(dir / "d.h5", 3, 16, 64);
  train::TrainConfig c = small_config(dir / "d.h5", "");
  const auto trained = train::train(c);
  const data::Dataset all = data::read_dataset(dir / "d.h5");
  const auto source = data::open_frame_source(dir / "d.h5");
  for (const auto& split : {data::reference_split(), data::parse_split("frames:1", 0, 64)}) {
    const data::Metrics want =
        data::evaluate_prediction(all, train::predict_dataset(*trained.model, c.encoder, all), true, split);
    const auto got = train::validate_frames(*trained.model, c.encoder, {source.get()}, split);
    ASSERT_EQ(got.size(), 1u);
    EXPECT_EQ(got[0].mae, want.mae);
    EXPECT_EQ(got[0].rmse, want.rmse);
    EXPECT_EQ(got[0].cells, want.cells);
    EXPECT_GT(want.cells, 0);
  }
}

namespace {
void write_vlen_attr(hid_t obj, const char* name, const std::string& value) {
  hid_t type = H5Tcopy(H5T_C_S1);
  H5Tset_size(type, H5T_VARIABLE);
  hid_t space = H5Screate(H5S_SCALAR);
  hid_t a = H5Acreate2(obj, name, type, space, H5P_DEFAULT, H5P_DEFAULT);
  const char* p = value.c_str();
  H5Awrite(a, type, &p);
  H5Aclose(a), H5Sclose(space), H5Tclose(type);
}
void write_vlen_strings(hid_t file, const char* name, const std::vector<std::string>& values) {
  hid_t type = H5Tcopy(H5T_C_S1);
  H5Tset_size(type, H5T_VARIABLE);
  hsize_t n = values.size();
  hid_t space = H5Screate_simple(1, &n, nullptr);
  hid_t ds = H5Dcreate2(file, name, type, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
  std::vector<const char*> ptrs;
  for (const auto& v : values) ptrs.push_back(v.c_str());
  H5Dwrite(ds, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, ptrs.data());
  H5Dclose(ds), H5Sclose(space), H5Tclose(type);
}
void write_contiguous(hid_t file, const char* name, hid_t type, std::vector<hsize_t> dims, const void* values) {
  hid_t space = H5Screate_simple(static_cast<int>(dims.size()), dims.data(), nullptr);
  hid_t ds = H5Dcreate2(file, name, type, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
  H5Dwrite(ds, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, values);
  H5Dclose(ds), H5Sclose(space);
}
// The same frames in the first dataset layout: contiguous arrays, variable-length strings, row
// modes in an attribute.
void write_old_format(const fs::path& path, const data::Dataset& d) {
  const hsize_t n = d.size(), c = d.channels.size(), h = d.rows(), w = d.cols();
  hid_t f = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  write_contiguous(f, "/pgm", H5T_NATIVE_FLOAT, {n, c, h, w}, d.pgm.data());
  write_contiguous(f, "/target", H5T_NATIVE_FLOAT, {n, 1, h, w}, d.target.data());
  std::vector<std::uint8_t> mask(d.mask.begin(), d.mask.end());
  write_contiguous(f, "/mask", H5T_NATIVE_UINT8, {n, 1, h, w}, mask.data());
  write_vlen_strings(f, "/frames", d.frames);
  write_vlen_strings(f, "/sources", {"old"});
  hid_t root = H5Gopen2(f, "/", H5P_DEFAULT);
  write_vlen_attr(root, "format", "lidarsim-dataset");
  write_vlen_attr(root, "channels", R"(["range","class","material"])");
  write_vlen_attr(root, "beam_layout", d.layout.to_json());
  write_vlen_attr(root, "source_format", "synthetic");
  std::string modes = "[";
  for (int i = 0; i < d.size(); ++i) modes += std::string(i ? "," : "") + "\"ring\"";
  write_vlen_attr(root, "row_modes", modes + "]");
  H5Gclose(root);
  H5Fclose(f);
}
}  // namespace

TEST(LazyTrain, OldContiguousFilesWithVariableLengthStringsTrainLikeNewOnes) {
  TempDir dir;
  write_synthetic(dir / "new.h5", 4, 16, 64);
  write_old_format(dir / "old.h5", data::read_dataset(dir / "new.h5"));
  hid_t f = H5Fopen((dir / "old.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  hid_t ds = H5Dopen2(f, "/pgm", H5P_DEFAULT), plist = H5Dget_create_plist(ds);
  EXPECT_EQ(H5Pget_layout(plist), H5D_CONTIGUOUS);
  H5Pclose(plist), H5Dclose(ds), H5Fclose(f);
  const auto from_new = train::train(small_config(dir / "new.h5", dir / "a.h5"));
  const auto from_old = train::train(small_config(dir / "old.h5", dir / "b.h5"));
  expect_same_epochs(from_new, from_old);
  EXPECT_TRUE(same_weights(from_new, from_old));
}

TEST(LazyTrain, ADamagedFrameIsNamedByFileArrayAndFrameAndStopsTheRun) {
  TempDir dir;
  write_synthetic(dir / "d.h5", 6, 16, 64);
  // Flip a byte inside frame 4's /pgm chunk (Fletcher-32 catches it when that frame is read).
  haddr_t address = 0;
  hsize_t chunk_bytes = 0;
  {
    hid_t f = H5Fopen((dir / "d.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
    hid_t ds = H5Dopen2(f, "/pgm", H5P_DEFAULT);
    const hsize_t origin[4] = {4, 0, 0, 0};
    unsigned filter_mask = 0;
    ASSERT_GE(H5Dget_chunk_info_by_coord(ds, origin, &filter_mask, &address, &chunk_bytes), 0);
    H5Dclose(ds), H5Fclose(f);
  }
  ASSERT_GT(chunk_bytes, 16u);
  {
    std::fstream io(dir / "d.h5", std::ios::in | std::ios::out | std::ios::binary);
    io.seekg(static_cast<std::streamoff>(address + chunk_bytes / 2));
    char byte = 0;
    io.read(&byte, 1);
    byte = static_cast<char>(byte ^ 0x10);
    io.seekp(static_cast<std::streamoff>(address + chunk_bytes / 2));
    io.write(&byte, 1);
  }
  for (const bool prefetch : {true, false}) {
    train::TrainConfig c = small_config(dir / "d.h5", dir / "ck.h5");
    c.prefetch = prefetch;
    c.epochs = 2;
    c.steps_per_epoch = 6;  // every frame is drawn in the first epoch (batch 2, 6 frames)
    try {
      train::train(c);
      FAIL() << "expected an error (prefetch " << prefetch << ")";
    } catch (const Error& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find("d.h5"), std::string::npos) << what;
      EXPECT_NE(what.find("/pgm"), std::string::npos) << what;
      EXPECT_NE(what.find("frame 4"), std::string::npos) << what;
    }
  }
}

TEST(LazyTrain, CtrlCEndsThePrefetchingThreadAndKeepsTheResumeExact) {
  TempDir dir;
  write_synthetic(dir / "d.h5", 5, 16, 64);
  train::TrainConfig c = small_config(dir / "d.h5", dir / "straight.h5");
  train::train(c);  // also starts OpenMP's worker threads, which stay
  const int threads_before = thread_count();
  train::TrainConfig split = small_config(dir / "d.h5", dir / "split.h5");
  const auto first = train::train(split, [](const train::EpochReport& r) {
    if (r.epoch == 1) train::stop_requested().store(true);  // as the SIGINT handler does
  });
  train::stop_requested().store(false);
  ASSERT_TRUE(first.interrupted);
  EXPECT_EQ(thread_count(), threads_before) << "the prefetching thread outlived the run";
  split.resume = true;
  train::train(split);
  EXPECT_EQ(read_bytes(dir / "straight.h5"), read_bytes(dir / "split.h5"));
}

// The run's peak memory holds a step's frames, not the dataset: 2,000 frames of 16 x 256 are
// 164 MB in memory (read_dataset), and training on them streams well under a tenth of that. What
// the peak does hold is a fixed working set (model, optimizer, the kernels' buffers): 12.6 MB where
// the 3x3 convolutions take the im2col + GEMM path (CPUs without AVX-512), so the set is large
// enough that a tenth of it clears that with margin.
TEST(LazyTrain, PeakMemoryStaysFarBelowTheDatasetsSizeOnManyFrames) {
  TempDir dir;
  const int frames = 2000, rows = 16, cols = 256;
  write_synthetic(dir / "many.h5", frames, rows, cols);
  const double in_memory_mb = frames * (5.0 * rows * cols * 4) / 1e6;  // pgm 3 ch + target + mask, floats
  train::TrainConfig c = small_config(dir / "many.h5", dir / "ck.h5");
  c.encoder.channels = {"range", "class"};
  c.epochs = 1;
  c.steps_per_epoch = 8;
  c.crop_columns = 64;
  c.cache_mb = 64;  // the set (164 MB) does not fit: no frame is kept
  // Peak RSS from here on: writing 5 to clear_refs resets VmHWM to the current RSS (Linux >= 4.0).
  std::ofstream("/proc/self/clear_refs") << "5";
  const long before_kb = status_kb("VmRSS:");
  ASSERT_GT(before_kb, 0);
  const auto result = train::train(c);  // validation predicts all 2,000 frames, one at a time
  const long peak_kb = status_kb("VmHWM:");
  ASSERT_EQ(result.epochs.size(), 1u);
  EXPECT_GT(result.epochs[0].validation.cells, 500L * frames);  // a quarter of the columns, 80 % returns
  const double grew_mb = (peak_kb - before_kb) / 1024.0;
  std::printf("dataset in memory %.0f MB; training peak RSS grew by %.1f MB\n", in_memory_mb, grew_mb);
  // AddressSanitizer keeps freed blocks in its quarantine (up to 256 MB, to catch use after free)
  // and pads every block with redzones: the peak grew by 90 MB there, 16 MB with
  // quarantine_size_mb=0, so it measures ASan, not what the training holds. The run above is
  // still checked for memory errors.
  if (lidarsim::testing::kSanitized)
    GTEST_SKIP() << "peak RSS bound not checked under AddressSanitizer (its quarantine keeps freed frames)";
  EXPECT_LT(grew_mb, in_memory_mb / 10);
}
