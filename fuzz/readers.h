#pragma once
// One fuzz entry per reader of outside input. Each takes arbitrary bytes, runs the reader on
// them (through a temporary file where the reader takes a path) and returns normally when the
// reader either accepts the input or rejects it with a lidarsim::Error. Anything else (a crash,
// another exception, a sanitizer report, a hang) is a finding. Built into libFuzzer executables
// by fuzz/CMakeLists.txt (LIDARSIM_FUZZ=ON, clang) and replayed over fuzz/regressions/ by the
// normal test suite (tests/fuzz).
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace lidarsim::fuzz {

using Entry = void (*)(const std::uint8_t* data, std::size_t size);

struct Target {
  std::string name;
  Entry run;
};

// Every target, by name (the name of its executable fuzz_<name> and its folders).
const std::vector<Target>& targets();
Entry find_target(const std::string& name);  // nullptr when unknown

}  // namespace lidarsim::fuzz
