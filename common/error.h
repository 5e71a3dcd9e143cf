#pragma once
// One exception type for bad input and failed I/O. Messages name the file, the field and
// what was expected; each command catches it at main, prints one line and exits non-zero.
#include <stdexcept>
#include <string>

namespace lidarsim {

class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// "file: field: message" — the shape every input error takes.
inline Error input_error(const std::string& file, const std::string& field, const std::string& message) {
  return Error(file + ": " + field + ": " + message);
}

}  // namespace lidarsim
