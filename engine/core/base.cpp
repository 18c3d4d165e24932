// Assert handler and error formatting.
#include "engine/core/base.h"

#include <atomic>
#include <cstdarg>
#include <filesystem>
#include <vector>

namespace zona {
namespace {

void default_assert_handler(const char* condition, const char* file, int line) {
  std::fprintf(stderr, "zona: assertion failed: %s (%s:%d)\n", condition, file, line);
  std::abort();
}

std::atomic<AssertHandler> g_assert_handler{&default_assert_handler};

}  // namespace

AssertHandler set_assert_handler(AssertHandler handler) {
  return g_assert_handler.exchange(handler ? handler : &default_assert_handler);
}

void assert_failed(const char* condition, const char* file, int line) {
  g_assert_handler.load()(condition, file, line);
}

const char* file_kind(const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  switch (fs::status(path, ec).type()) {
    case fs::file_type::regular:
      return "regular file";
    case fs::file_type::directory:
      return "directory";
    case fs::file_type::character:
      return "character device";
    case fs::file_type::block:
      return "block device";
    case fs::file_type::fifo:
      return "FIFO";
    case fs::file_type::socket:
      return "socket";
    case fs::file_type::none:
    case fs::file_type::not_found:
      return "";
    default:
      return "special file";
  }
}

Status check_regular_file(const std::string& path) {
  const std::string kind = file_kind(path);
  if (kind.empty()) return make_error("%s: cannot open: no such file", path.c_str());
  if (kind != "regular file")
    return make_error("%s: is not a regular file (%s)", path.c_str(), kind.c_str());
  return Status::ok_status();
}

Error make_error(const char* format, ...) {
  va_list args;
  va_start(args, format);
  va_list copy;
  va_copy(copy, args);
  const int n = std::vsnprintf(nullptr, 0, format, copy);
  va_end(copy);
  std::string text(n > 0 ? static_cast<size_t>(n) : 0, '\0');
  if (n > 0) std::vsnprintf(text.data(), text.size() + 1, format, args);
  va_end(args);
  return Error{std::move(text)};
}

std::string program_dir() {
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  return ec ? std::string() : exe.parent_path().string();
}

}  // namespace zona
