// The commands under hostile conditions: a full disk (a file-size limit), two trainers on one
// output, temporaries left by a killed run, impossible numbers on the command line, unreadable
// scans. Each ends in one clear error and a non-zero exit, with the previous output intact.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "data/dataset.h"
#include "tests/support/file_bytes.h"
#include "tests/support/shared_data.h"

using lidarsim::testing::read_bytes;

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

fs::path exe(const std::string& folder, const std::string& name) { return lidarsim::testing::binary_dir() / folder / name; }

struct CmdResult {
  int code = -1;
  std::string err;
};

// Runs `command` under bash (so `ulimit` works); SIGXFSZ ignored, as a full disk would give EFBIG/ENOSPC.
CmdResult run_cli(const std::string& command, const fs::path& dir) {
  const fs::path err = dir / "stderr.txt";
  const std::string line = "bash -c 'trap \"\" XFSZ; " + command + "' >/dev/null 2>" + err.string();
  const int rc = std::system(line.c_str());
  CmdResult r;
  r.code = WIFEXITED(rc) ? WEXITSTATUS(rc) : 128 + WTERMSIG(rc);
  r.err = read_bytes(err);
  return r;
}

int error_lines(const std::string& err) {
  int n = 0;
  for (std::size_t at = err.find("error:"); at != std::string::npos; at = err.find("error:", at + 1)) ++n;
  return n;
}

struct Dir {
  fs::path path;
  explicit Dir(const std::string& name) {
    path = fs::temp_directory_path() / ("lidarsim_rel_cli_" + name + "_" + std::to_string(::getpid()));
    fs::remove_all(path);
    fs::create_directories(path);
  }
  ~Dir() { fs::remove_all(path); }
  fs::path operator/(const std::string& s) const { return path / s; }
};

// A small synthetic training set (16 x 256 grids: the guarded split needs room for
// its guard bands, twice the receptive-field half-width of 23 columns, around a quarter circle).
fs::path small_dataset(const Dir& dir) {
  data::Dataset set;
  set.channels = {"range", "class", "material"};
  const auto layout = pgm::BeamLayout::uniform(16, 2.0, -24.0, 256);
  for (int f = 0; f < 2; ++f) {
    pgm::PolarGridMap map(layout, {"range", "class", "material", "intensity", "mask"});
    for (int r = 0; r < map.rows(); ++r)
      for (int c = 0; c < map.cols(); ++c) {
        map.at(0, r, c) = 4.f + r + std::sin(0.1f * c + f);
        map.at(1, r, c) = 40.f;
        map.at(2, r, c) = 1.f;
        map.at(3, r, c) = 0.3f + 0.01f * r;
        map.at(4, r, c) = 1.f;
      }
    set.append(map, "f" + std::to_string(f), "ring");
  }
  const fs::path path = dir / "set.h5";
  data::write_dataset(path, set);
  return path;
}

std::string train_cmd(const fs::path& data, const fs::path& out, const std::string& extra = "") {
  return exe("train", "lidar-train").string() + " --quiet --data " + data.string() + " --out " + out.string() +
         " --base 4 --depth 2 --epochs 2 --steps-per-epoch 2 --threads 1 " + extra;
}

std::string sample_scans() { return (lidarsim::testing::source_dir() / "data/samples/semantickitti").string(); }

}  // namespace

TEST(CliReliability, ImportOnAFullDiskGivesOneErrorAndKeepsThePreviousDataset) {
  Dir dir("import_full");
  const fs::path out = dir / "sk.h5";
  const std::string import = exe("data", "lidar-data").string() + " import --quiet --semantickitti " + sample_scans() +
                             " --out " + out.string();
  ASSERT_EQ(run_cli(import, dir.path).code, 0);
  const std::string before = read_bytes(out);
  const CmdResult full = run_cli("ulimit -f 64; " + import + " --columns 512", dir.path);
  EXPECT_EQ(full.code, 1) << full.err;
  EXPECT_EQ(error_lines(full.err), 1) << full.err;
  EXPECT_NE(full.err.find(out.string()), std::string::npos) << full.err;
  EXPECT_EQ(read_bytes(out), before);
}

TEST(CliReliability, TrainOnAFullDiskGivesOneErrorAndKeepsThePreviousCheckpoint) {
  Dir dir("train_full");
  const fs::path data = small_dataset(dir), out = dir / "ck.h5";
  ASSERT_EQ(run_cli(train_cmd(data, out), dir.path).code, 0);
  const std::string before = read_bytes(out);
  const CmdResult full = run_cli("ulimit -f 4; " + train_cmd(data, out, "--seed 9"), dir.path);
  EXPECT_EQ(full.code, 1) << full.err;
  EXPECT_EQ(error_lines(full.err), 1) << full.err;
  EXPECT_EQ(read_bytes(out), before);
}

TEST(CliReliability, SimOnAFullDiskGivesOneErrorAndKeepsThePreviousSummary) {
  Dir dir("sim_full");
  const std::string sim =
      exe("infer", "lidar-infer").string() + " sim --quiet --frames 1 --threads 1 --out " + (dir / "sim").string();
  ASSERT_EQ(run_cli(sim, dir.path).code, 0);
  const std::string before = read_bytes(dir / "sim" / "summary.json");
  ASSERT_FALSE(before.empty());
  const CmdResult full = run_cli("ulimit -f 8; " + sim + " --seed 5", dir.path);
  EXPECT_EQ(full.code, 1) << full.err;
  EXPECT_EQ(error_lines(full.err), 1) << full.err;
  EXPECT_EQ(read_bytes(dir / "sim" / "summary.json"), before);
}

TEST(CliReliability, SecondTrainerOnTheSameOutputIsRefused) {
  Dir dir("lock");
  const fs::path data = small_dataset(dir), out = dir / "ck.h5";
  // The first trainer runs long enough (many steps) for the second to meet it.
  const std::string first = train_cmd(data, out, "--epochs 400 --steps-per-epoch 5") + " >/dev/null 2>&1 &";
  std::system(("bash -c '" + first + " echo $! > " + (dir / "pid").string() + "'").c_str());
  ::usleep(700 * 1000);
  const CmdResult second = run_cli(train_cmd(data, out), dir.path);
  std::system(("kill $(cat " + (dir / "pid").string() + ") 2>/dev/null; sleep 0.2").c_str());
  EXPECT_NE(second.code, 0) << second.err;
  EXPECT_NE(second.err.find("another"), std::string::npos) << second.err;
}

TEST(CliReliability, StaleTemporariesOfDeadRunsAreRemoved) {
  Dir dir("stale");
  const fs::path data = small_dataset(dir), out = dir / "ck.h5";
  // pid 4194304 is above Linux's largest (pid_max <= 2^22): no such process can be running.
  const fs::path stale = dir / "ck.h5.tmp.4194304", alive = dir / ("ck.h5.tmp." + std::to_string(::getpid()));
  std::ofstream(stale) << "torn";
  std::ofstream(alive) << "in flight";
  ASSERT_EQ(run_cli(train_cmd(data, out), dir.path).code, 0);
  EXPECT_FALSE(fs::exists(stale));
  EXPECT_TRUE(fs::exists(alive)) << "a temporary of a live process must stay";
}

TEST(CliReliability, ImpossibleNumbersOnTheCommandLineAreRefused) {
  Dir dir("numbers");
  const fs::path data = small_dataset(dir), out = dir / "ck.h5";
  for (const std::string bad : {"--steps-per-epoch -5", "--crop -64", "--crop 7", "--threads 0", "--depth 0",
                                "--batch 1000000000", "--epochs -1", "--lr -1"}) {
    const CmdResult r = run_cli(train_cmd(data, out, bad), dir.path);
    EXPECT_NE(r.code, 0) << "lidar-train " << bad;
    EXPECT_EQ(error_lines(r.err), 1) << bad << ": " << r.err;
  }
  const std::string import = exe("data", "lidar-data").string() + " import --quiet --semantickitti " + sample_scans() +
                             " --out " + (dir / "d.h5").string();
  for (const std::string bad : {"--first -1", "--max-frames -1", "--columns 1048576"}) {
    const CmdResult r = run_cli(import + " " + bad, dir.path);
    EXPECT_NE(r.code, 0) << "lidar-data import " << bad;
    EXPECT_EQ(error_lines(r.err), 1) << bad << ": " << r.err;
  }
  const std::string sim = exe("infer", "lidar-infer").string() + " sim --quiet --no-outputs --out " + (dir / "sim").string();
  for (const std::string bad : {"--frames -1", "--threads 0"}) {
    const CmdResult r = run_cli(sim + " " + bad, dir.path);
    EXPECT_NE(r.code, 0) << "lidar-infer sim " << bad;
    EXPECT_EQ(error_lines(r.err), 1) << bad << ": " << r.err;
  }
}

TEST(CliReliability, SimWarningNamesTheColumnCountWhenOnlyItDiffers) {
  Dir dir("columns");
  std::string scenario = read_bytes(lidarsim::testing::source_dir() / "data/scenarios/demo_urban.json");
  const std::size_t at = scenario.find("\"columns\": 1024");
  ASSERT_NE(at, std::string::npos);
  scenario.replace(at, 15, "\"columns\": 512");
  std::ofstream(dir / "s.json") << scenario;
  const CmdResult r = run_cli(exe("infer", "lidar-infer").string() + " sim --quiet --no-outputs --frames 1 --scenario " +
                        (dir / "s.json").string() + " --out " + (dir / "sim").string(),
                    dir.path);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("columns 1024 vs 512"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("rows"), std::string::npos) << "only the column count differs: " << r.err;
}

TEST(CliReliability, UnreadableScansAreAnErrorOrWithTheOptionSkippedAndCounted) {
  Dir dir("skip");
  const fs::path seq = dir / "sk" / "00";
  fs::create_directories(seq / "velodyne");
  fs::create_directories(seq / "labels");
  const fs::path sample = lidarsim::testing::source_dir() / "data/samples/semantickitti/sequences/00";
  fs::copy_file(sample / "velodyne/000000.bin", seq / "velodyne/000000.bin");
  fs::copy_file(sample / "labels/000000.label", seq / "labels/000000.label");
  fs::create_symlink(dir / "missing.bin", seq / "velodyne/000001.bin");
  fs::copy_file(sample / "labels/000000.label", seq / "labels/000001.label");
  const std::string import = exe("data", "lidar-data").string() + " import --quiet --semantickitti " +
                             (dir / "sk").string() + " --out " + (dir / "d.h5").string();
  const CmdResult strict = run_cli(import, dir.path);
  EXPECT_EQ(strict.code, 1) << strict.err;
  EXPECT_NE(strict.err.find("000001.bin"), std::string::npos) << strict.err;
  const CmdResult lenient = run_cli(import + " --skip-unreadable", dir.path);
  EXPECT_EQ(lenient.code, 0) << lenient.err;
  EXPECT_NE(lenient.err.find("found 2 scans, read 1, skipped 1"), std::string::npos) << lenient.err;
  EXPECT_NE(lenient.err.find("000001.bin"), std::string::npos) << lenient.err;
}

TEST(CliReliability, PredictNamesLabelsOutsideTheClassTable) {
  Dir dir("labels");
  const fs::path sample = lidarsim::testing::source_dir() / "data/samples/semantickitti/sequences/00";
  std::string labels = read_bytes(sample / "labels/000000.label");
  const std::uint32_t odd = 9999;
  std::memcpy(labels.data(), &odd, 4);
  std::ofstream(dir / "odd.label", std::ios::binary) << labels;
  const CmdResult r = run_cli(exe("infer", "lidar-infer").string() + " predict --quiet --model " +
                        (lidarsim::testing::source_dir() / "data/models/intensity_unet.h5").string() + " --scan " +
                        (sample / "velodyne/000000.bin").string() + " --label " + (dir / "odd.label").string() +
                        " --out " + (dir / "p").string(),
                    dir.path);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("outside"), std::string::npos) << r.err;
}

TEST(CliReliability, TrainingsKilledAtRandomMomentsResumeToTheUninterruptedCheckpoint) {
  Dir dir("crash");
  // scripts/crash_test.sh: 5 runs here, up to 3 SIGKILLs each; `--count 20` by hand.
  const CmdResult r = run_cli((lidarsim::testing::source_dir() / "scripts/crash_test.sh").string() + " --count 5 --build " +
                              lidarsim::testing::binary_dir().string() + " 2>&1 | tee " + (dir / "log.txt").string() +
                              " >&2; exit ${PIPESTATUS[0]}",
                          dir.path);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("5 of 5 runs ended byte-identical"), std::string::npos) << r.err;
}
