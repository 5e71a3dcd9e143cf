#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "common/atomic_file.h"
#include "common/error.h"
#include "common/image.h"
#include "tests/support/temp_path.h"

namespace fs = std::filesystem;
using namespace lidarsim;

TEST(Image, ViridisEndsAreDarkPurpleAndYellow) {
  const Rgb lo = colormap_viridis(0.f), hi = colormap_viridis(1.f);
  EXPECT_EQ(lo.r, 68);
  EXPECT_EQ(lo.b, 84);
  EXPECT_EQ(hi.r, 253);
  EXPECT_EQ(hi.g, 231);
  EXPECT_EQ(colormap_viridis(-3.f).r, lo.r);  // clamped
}

TEST(Image, WritePngProducesAPngSignatureAndNoTemporaryFile) {
  const fs::path dir = lidarsim::testing::temp_path("test_image");
  fs::create_directories(dir);
  const fs::path path = dir / "a.png";
  Image image(5, 3, {10, 20, 30});
  image.at(4, 2) = {255, 0, 0};
  write_png(path, image);
  std::ifstream in(path, std::ios::binary);
  char sig[8] = {};
  in.read(sig, 8);
  EXPECT_EQ(std::string(sig + 1, 3), "PNG");
  for (const auto& entry : fs::directory_iterator(dir)) EXPECT_EQ(entry.path().filename(), "a.png");
  fs::remove_all(dir);
}

TEST(AtomicFile, UncommittedWriteLeavesTheOldFileIntact) {
  const fs::path path = lidarsim::testing::temp_path("atomic.txt");
  write_file_atomically(path, "old");
  {
    AtomicFile file(path);
    std::ofstream(file.temp_path()) << "half-written";
    // no commit: as if the run were killed
  }
  std::ifstream in(path);
  std::string text;
  in >> text;
  EXPECT_EQ(text, "old");
  fs::remove(path);
}

TEST(Image, StackingImagesOfDifferentWidthIsAnError) {
  EXPECT_THROW(stack_vertically({Image(3, 1), Image(4, 1)}), Error);
}
