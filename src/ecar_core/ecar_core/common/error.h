// Errors raised by ecar_core. The core never prints: it throws an ecar::Error
// whose text names what was wrong (the file, line or key), and the caller (a
// CLI, a ROS wrapper) decides how to report it.
#pragma once

#include <stdexcept>
#include <string>

namespace ecar {

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what) : std::runtime_error(what) {}
};

}  // namespace ecar
