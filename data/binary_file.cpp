#include "data/binary_file.h"

#include <fstream>

#include "common/error.h"

namespace lidarsim::data {

std::vector<char> read_binary_file(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw input_error(path.string(), "file", "not found or not a file");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw input_error(path.string(), "file", "cannot be opened");
  std::vector<char> bytes(std::filesystem::file_size(path));
  if (!bytes.empty() && !in.read(bytes.data(), static_cast<std::streamsize>(bytes.size())))
    throw input_error(path.string(), "file", "read failed");
  return bytes;
}

}  // namespace lidarsim::data
