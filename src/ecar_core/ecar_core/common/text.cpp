#include "ecar_core/common/text.h"

#include <charconv>
#include <cmath>
#include <locale>
#include <sstream>

namespace ecar {

bool parseDouble(const std::string& text, double* value) {
  const char* begin = text.data();
  const char* end = text.data() + text.size();
  if (begin != end && *begin == '+') ++begin;  // from_chars rejects an explicit '+'
  if (begin == end) return false;
#if defined(__cpp_lib_to_chars) && __cpp_lib_to_chars >= 201611L
  const auto [ptr, ec] = std::from_chars(begin, end, *value);
  if (ec == std::errc::result_out_of_range && ptr == end) {
    *value = (*begin == '-') ? -HUGE_VAL : HUGE_VAL;
    return true;
  }
  return ec == std::errc() && ptr == end;
#else
  // Older standard libraries (GCC < 11) have no floating-point from_chars.
  std::istringstream in(std::string(begin, end));
  in.imbue(std::locale::classic());
  in >> *value;
  if (in.fail()) {
    // Out of range sets failbit with +-max: report it as non-finite.
    if (std::fabs(*value) > 0) {
      *value = *value > 0 ? HUGE_VAL : -HUGE_VAL;
      return in.eof();
    }
    return false;
  }
  return in.eof() || (in >> std::ws).eof();
#endif
}

std::vector<std::string> splitWhitespace(const std::string& line) {
  std::vector<std::string> fields;
  std::istringstream in(line);
  std::string field;
  while (in >> field) fields.push_back(field);
  return fields;
}

std::string quote(const std::string& s) { return "'" + s + "'"; }

}  // namespace ecar
