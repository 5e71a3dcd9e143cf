#include "common/image.h"

#include <png.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>

#include "common/atomic_file.h"
#include "common/error.h"

namespace lidarsim {

Rgb colormap_viridis(float t) {
  // Eight anchor colours of viridis, linearly interpolated.
  static constexpr std::array<std::array<float, 3>, 8> anchors{{{68, 1, 84},
                                                               {70, 50, 126},
                                                               {54, 92, 141},
                                                               {39, 127, 142},
                                                               {31, 161, 135},
                                                               {74, 193, 109},
                                                               {160, 218, 57},
                                                               {253, 231, 37}}};
  if (!std::isfinite(t)) t = 0.f;
  t = std::clamp(t, 0.f, 1.f) * (anchors.size() - 1);
  const size_t i = std::min<size_t>(static_cast<size_t>(t), anchors.size() - 2);
  const float f = t - static_cast<float>(i);
  auto mix = [&](int c) {
    return static_cast<std::uint8_t>(std::lround(anchors[i][c] * (1 - f) + anchors[i + 1][c] * f));
  };
  return {mix(0), mix(1), mix(2)};
}

Rgb colormap_category(int index) {
  static constexpr std::array<Rgb, 12> palette{{{31, 119, 180},
                                                {255, 127, 14},
                                                {44, 160, 44},
                                                {214, 39, 40},
                                                {148, 103, 189},
                                                {140, 86, 75},
                                                {227, 119, 194},
                                                {127, 127, 127},
                                                {188, 189, 34},
                                                {23, 190, 207},
                                                {255, 255, 255},
                                                {255, 215, 0}}};
  if (index < 0) return {0, 0, 0};
  return palette[static_cast<size_t>(index) % palette.size()];
}

Image field_to_image(const float* values, const std::uint8_t* valid, int width, int height, float lo, float hi,
                     Rgb invalid) {
  Image image(width, height, invalid);
  const float span = hi > lo ? hi - lo : 1.f;
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      const size_t i = static_cast<size_t>(y) * width + x;
      if (valid && !valid[i]) continue;
      image.at(x, y) = colormap_viridis((values[i] - lo) / span);
    }
  return image;
}

Image stack_vertically(const std::vector<Image>& parts, int gap, Rgb gap_colour) {
  if (parts.empty()) return {};
  int height = 0;
  for (const auto& p : parts) {
    if (p.width != parts[0].width) throw Error("stack_vertically: images differ in width");
    height += p.height;
  }
  height += gap * static_cast<int>(parts.size() - 1);
  Image out(parts[0].width, height, gap_colour);
  int y0 = 0;
  for (const auto& p : parts) {
    std::copy(p.pixels.begin(), p.pixels.end(), out.pixels.begin() + static_cast<ptrdiff_t>(y0) * out.width);
    y0 += p.height + gap;
  }
  return out;
}

Image scale_rows(const Image& image, int factor) {
  Image out(image.width, image.height * factor);
  for (int y = 0; y < out.height; ++y)
    for (int x = 0; x < out.width; ++x) out.at(x, y) = image.at(x, y / factor);
  return out;
}

void write_png(const std::filesystem::path& path, const Image& image) {
  if (image.width <= 0 || image.height <= 0) throw Error(path.string() + ": cannot write an empty image");
  AtomicFile file(path);
  FILE* fp = std::fopen(file.temp_path().c_str(), "wb");
  if (!fp) throw Error(path.string() + ": cannot open for writing");
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!png || !info || setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    std::fclose(fp);
    throw Error(path.string() + ": libpng failed while writing");
  }
  png_init_io(png, fp);
  // The simulator writes images every frame: zlib's fastest level with the Sub filter encodes
  // several times faster than the defaults for files a little larger (simulation outputs must
  // keep up with the pipeline; README, Outputs off the critical path).
  png_set_compression_level(png, 1);
  png_set_filter(png, PNG_FILTER_TYPE_BASE, PNG_FILTER_SUB);
  png_set_IHDR(png, info, image.width, image.height, 8, PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE,
               PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  for (int y = 0; y < image.height; ++y) {
    auto* row = reinterpret_cast<png_bytep>(const_cast<Rgb*>(&image.pixels[static_cast<size_t>(y) * image.width]));
    png_write_row(png, row);
  }
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  if (std::fclose(fp) != 0) throw Error(path.string() + ": write failed");
  file.commit();
}

}  // namespace lidarsim
