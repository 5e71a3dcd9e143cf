#pragma once
// A file's bytes as a string, and back: the checkpoint tests compare files byte for byte and
// corrupt them in place.
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

namespace lidarsim::testing {

inline std::string read_bytes(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

inline void write_bytes(const std::filesystem::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

}  // namespace lidarsim::testing
