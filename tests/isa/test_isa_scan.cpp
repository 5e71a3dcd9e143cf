// The shipped binaries run on any x86-64-v3 CPU: no function outside the dispatched AVX-512
// kernels (names with "avx512", chosen at run time by nn/cpu_features.h) uses an instruction
// beyond x86-64-v3. A build with -march=native on an AVX-512 machine (or LIDARSIM_ARCH=x86-64-v4)
// fails here: the compiler then puts AVX-512 into ordinary code (Eigen, loops it vectorises).
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "isa_scan.h"

namespace {

namespace fs = std::filesystem;
using lidarsim::testing::scan_disassembly;

bool have_objdump() { return std::system("objdump --version >/dev/null 2>&1") == 0; }

std::string disassemble(const fs::path& file) {
  const std::string cmd = "objdump -d -C -w '" + file.string() + "' 2>/dev/null";
  FILE* pipe = popen(cmd.c_str(), "r");
  if (!pipe) return "";
  std::string out;
  char buf[1 << 16];
  for (std::size_t got; (got = std::fread(buf, 1, sizeof buf, pipe)) > 0;) out.append(buf, got);
  pclose(pipe);
  return out;
}

// lidar-infer and every shared object the FMU ships (its binaries/linux64 folder, whatever it
// holds); LIDARSIM_ISA_SCAN_FILES (paths separated by ':') scans those files instead.
std::vector<fs::path> shipped_binaries() {
  if (const char* env = std::getenv("LIDARSIM_ISA_SCAN_FILES"); env && *env) {
    std::vector<fs::path> files;
    std::string list = env;
    for (std::size_t start = 0, end; start <= list.size(); start = end + 1) {
      end = std::min(list.find(':', start), list.size());
      if (end > start) files.emplace_back(list.substr(start, end - start));
    }
    return files;
  }
  const fs::path build = LIDARSIM_BINARY_DIR;
  std::vector<fs::path> files{build / "infer" / "lidar-infer"};
  const fs::path fmu_bin = build / "infer" / "fmu" / "lidarsim_osi_fmu" / "binaries" / "linux64";
  if (fs::is_directory(fmu_bin))
    for (const auto& e : fs::directory_iterator(fmu_bin))
      if (e.path().extension() == ".so") files.push_back(e.path());
  return files;
}

TEST(IsaScan, FindsAvx512OutsideTheKernelsAndNothingElse) {
  std::istringstream dis(
      "0000000000001000 <lidarsim::nn::detail::avx512::conv(float*)>:\n"
      "    1000:\t62 f1 7c 48 10 0f    \tvmovups (%rdi),%zmm1\n"
      "0000000000001010 <Eigen::gemm(float*)>:\n"
      "    1010:\tc5 fc 10 0f          \tvmovups (%rdi),%ymm1\n"
      "    1014:\tc4 e2 7d b8 c1       \tvfmadd231ps %ymm1,%ymm0,%ymm0\n"
      "0000000000001020 <evex_with_low_registers(float*)>:\n"
      "    1020:\t62 f1 7d 28 6f 07    \tvmovdqa32 (%rdi),%ymm0\n"
      "0000000000001030 <mask_op(int)>:\n"
      "    1030:\tc5 f8 92 c8          \tkmovw %eax,%k1\n"
      "0000000000001040 <high_ymm(float*)>:\n"
      "    1040:\t67 62 e1 7c 28 10 07 \tvmovups (%edi),%ymm16\n"
      "0000000000001050 <std::vector<float>::resize(unsigned long)>:\n"
      "    1050:\tc5 f8 77             \tvzeroupper\n"
      "0000000000001060 <lidarsim::nn::detail::avx512_amx::forward(float*)>:\n"
      "    1060:\tc4 e2 78 49 07       \tldtilecfg (%rdi)\n"
      "    1065:\tc4 e2 7b 4b 04 3e    \ttileloadd (%rsi,%rdi,1),%tmm0\n"
      "0000000000001070 <tile_config(void const*)>:\n"
      "    1070:\tc4 e2 78 49 07       \tldtilecfg (%rdi)\n"
      "0000000000001080 <tile_release()>:\n"
      "    1080:\tc4 e2 78 49 c0       \ttilerelease\n"
      "0000000000001090 <tile_dot()>:\n"
      "    1090:\tc4 e2 72 5c c2       \ttdpbf16ps %tmm1,%tmm2,%tmm0\n");
  const auto found = scan_disassembly(dis);
  ASSERT_EQ(found.size(), 6u);
  EXPECT_EQ(found[0].function, "evex_with_low_registers(float*)");
  EXPECT_EQ(found[1].function, "mask_op(int)");
  EXPECT_EQ(found[2].function, "high_ymm(float*)");
  EXPECT_EQ(found[3].function, "tile_config(void const*)");
  EXPECT_EQ(found[4].function, "tile_release()");
  EXPECT_EQ(found[5].function, "tile_dot()");
}

TEST(IsaScan, ShippedBinariesUseNothingBeyondX86_64V3OutsideTheKernels) {
  if (!have_objdump()) GTEST_SKIP() << "objdump not found (binutils): the ISA scan needs it";
  for (const fs::path& file : shipped_binaries()) {
    ASSERT_TRUE(fs::exists(file)) << file << " is not built";
    std::istringstream dis(disassemble(file));
    ASSERT_GT(dis.str().size(), 1000u) << "objdump gave no disassembly of " << file;
    const auto found = scan_disassembly(dis);
    std::ostringstream msg;
    for (std::size_t i = 0; i < found.size() && i < 20; ++i)  // template names run to pages
      msg << "\n  " << found[i].function.substr(0, 160) << ": " << found[i].instruction.substr(0, 60);
    EXPECT_TRUE(found.empty()) << file << ": " << found.size()
                               << " functions outside the dispatched kernels use instructions beyond x86-64-v3"
                               << " (first 20):" << msg.str();
  }
}

}  // namespace
