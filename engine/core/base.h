// Basic definitions shared by every zona file: host/device markers, the assert, error values.
#pragma once

#include <cassert>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <utility>
#include <variant>

// Functions marked ZONA_HOST_DEVICE compile for the CPU and, under nvcc, for the GPU too:
// per-element math lives in such functions so the two backends cannot drift apart.
#if defined(__CUDACC__)
#define ZONA_HOST_DEVICE __host__ __device__
#define ZONA_INLINE __forceinline__
#else
#define ZONA_HOST_DEVICE
#define ZONA_INLINE inline
#endif

// ZONA_ASSERT catches programmer mistakes. It is on in debug, validation and sanitizer builds
// and compiles to nothing in release builds. The handler can be replaced (tests, embedding apps).
namespace zona {
using AssertHandler = void (*)(const char* condition, const char* file, int line);
/// Replaces the assert handler; returns the previous one. The default prints and aborts.
AssertHandler set_assert_handler(AssertHandler handler);
/// Calls the current assert handler (used by ZONA_ASSERT).
void assert_failed(const char* condition, const char* file, int line);
}  // namespace zona

#if !defined(NDEBUG) || defined(ZONA_ENABLE_ASSERT)
#if defined(__CUDA_ARCH__)
#define ZONA_ASSERT(c) assert(c)
#else
#define ZONA_ASSERT(c) ((c) ? (void)0 : ::zona::assert_failed(#c, __FILE__, __LINE__))
#endif
#else
#define ZONA_ASSERT(c) ((void)0)
#endif

namespace zona {

/// An error from fallible setup (files, scenes, devices): one line a person can act on, naming
/// the file, line, key or element at fault.
struct Error {
  std::string message;
};

/// Either a value or an Error. Setup functions return it; the step and haptic paths never do.
template <class T>
class [[nodiscard]] Result {
 public:
  Result(T value) : data_(std::move(value)) {}  // NOLINT: implicit by design
  Result(Error error) : data_(std::move(error)) {}  // NOLINT: implicit by design

  bool ok() const { return data_.index() == 0; }
  explicit operator bool() const { return ok(); }
  T& value() & { ZONA_ASSERT(ok()); return std::get<0>(data_); }
  const T& value() const& { ZONA_ASSERT(ok()); return std::get<0>(data_); }
  T&& value() && { ZONA_ASSERT(ok()); return std::get<0>(std::move(data_)); }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }
  const Error& error() const { ZONA_ASSERT(!ok()); return std::get<1>(data_); }

 private:
  std::variant<T, Error> data_;
};

/// Result for operations that return nothing but may fail.
class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(Error error) : error_(std::move(error.message)), failed_(true) {}  // NOLINT
  static Status ok_status() { return {}; }
  bool ok() const { return !failed_; }
  explicit operator bool() const { return ok(); }
  Error error() const { return Error{error_}; }

 private:
  std::string error_;
  bool failed_ = false;
};

/// What a path names, in words for messages: "regular file", "directory", "character device",
/// "block device", "FIFO", "socket" or "special file"; "" when nothing is there (a dangling
/// link included). Readers look before they open: a FIFO blocks the open and a device such as
/// /dev/zero never ends, so anything but a regular file is refused with this word.
const char* file_kind(const std::string& path);

/// Ok for a regular file; else "PATH: cannot open: no such file" or "PATH: is not a regular
/// file (KIND)" with file_kind's word. For readers of files named by a user, before opening.
Status check_regular_file(const std::string& path);

/// The running program's folder (from /proc/self/exe; "" where that is not there): where an
/// installed zona finds its data relative to itself.
std::string program_dir();

/// Builds an Error from printf-style arguments.
#if defined(__GNUC__)
__attribute__((format(printf, 1, 2)))
#endif
Error make_error(const char* format, ...);

}  // namespace zona
