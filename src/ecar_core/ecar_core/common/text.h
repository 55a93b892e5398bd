// Small text helpers shared by the file readers.
#pragma once

#include <string>
#include <vector>

namespace ecar {

/// Parses the whole of `text` as a double, independently of the C locale.
/// Returns false when it is not a number. An explicit '+' is accepted; values
/// out of range come back as +-HUGE_VAL (non-finite: callers report them).
bool parseDouble(const std::string& text, double* value);

/// s in single quotes, for error messages: 's'.
std::string quote(const std::string& s);

/// Splits a line at runs of whitespace.
std::vector<std::string> splitWhitespace(const std::string& line);

}  // namespace ecar
