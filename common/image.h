#pragma once
// RGB images, colour maps and PNG output (libpng), for pictures people look at.
#include <cstdint>
#include <filesystem>
#include <vector>

namespace lidarsim {

struct Rgb {
  std::uint8_t r = 0, g = 0, b = 0;
};

struct Image {
  int width = 0, height = 0;
  std::vector<Rgb> pixels;  // row-major, height x width
  Image() = default;
  Image(int w, int h, Rgb fill = {}) : width(w), height(h), pixels(static_cast<size_t>(w) * h, fill) {}
  Rgb& at(int x, int y) { return pixels[static_cast<size_t>(y) * width + x]; }
  const Rgb& at(int x, int y) const { return pixels[static_cast<size_t>(y) * width + x]; }
};

// Perceptually ordered colour map (viridis-like) of t in [0, 1]; values outside are clamped.
Rgb colormap_viridis(float t);
// Distinct colours for categorical values (class ids, track ids).
Rgb colormap_category(int index);

// Scale a row-major height x width field into an image; cells where valid is false get `invalid`.
Image field_to_image(const float* values, const std::uint8_t* valid, int width, int height, float lo, float hi,
                     Rgb invalid = {0, 0, 0});

// Stack images vertically (widths must match), separated by `gap` rows of `gap_colour`.
Image stack_vertically(const std::vector<Image>& parts, int gap = 2, Rgb gap_colour = {255, 255, 255});

// Nearest-neighbour upscale in y only (range images are wide and short).
Image scale_rows(const Image& image, int factor);

// Write an 8-bit RGB PNG, atomically (temporary file + rename).
void write_png(const std::filesystem::path& path, const Image& image);

}  // namespace lidarsim
