#pragma once
// Whole binary files, with errors that name the file.
#include <filesystem>
#include <vector>

namespace lidarsim::data {

std::vector<char> read_binary_file(const std::filesystem::path& path);

}  // namespace lidarsim::data
