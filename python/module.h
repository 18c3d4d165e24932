// Shared parts of the Python module's C++ files (python/module*.cpp): the error type that becomes
// zona.ZonaError, and numpy arrays over C++ storage that keep that storage alive (no copy).
#pragma once

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "engine/core/base.h"
#include "engine/core/vec.h"

namespace zona::py {

namespace nb = nanobind;

/// A zona error: one line naming the file, key or value. Raised in Python as zona.ZonaError.
struct ZonaError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

/// The value of `r`, or its error thrown as ZonaError.
template <class T>
T take(Result<T> r) {
  if (!r.ok()) throw ZonaError(r.error().message);
  return std::move(r).value();
}

/// Throws a failed status as ZonaError.
inline void check(const Status& s) {
  if (!s.ok()) throw ZonaError(s.error().message);
}

/// A numpy array of `shape` over `data`, which `keeper` keeps alive as long as the array lives:
/// the array is a view, nothing is copied.
template <class T>
nb::object array_view(const T* data, std::vector<size_t> shape, std::shared_ptr<const void> keeper) {
  auto* hold = new std::shared_ptr<const void>(std::move(keeper));
  nb::capsule owner(hold, [](void* p) noexcept { delete static_cast<std::shared_ptr<const void>*>(p); });
  nb::ndarray<nb::numpy, T> array(const_cast<T*>(data), shape.size(), shape.data(), owner);
  return nb::cast(array);
}

/// A numpy array of `shape` that takes over `values` (moved, not copied).
template <class T>
nb::object array_of(std::vector<T>&& values, std::vector<size_t> shape) {
  auto storage = std::make_shared<std::vector<T>>(std::move(values));
  const T* data = storage->data();
  return array_view(data, std::move(shape), std::move(storage));
}

/// Positions [m] as an (n x 3) float64 array over `positions` (Vec3d is three doubles).
inline nb::object positions_view(const std::vector<Vec3d>& positions,
                                 std::shared_ptr<const void> keeper) {
  static_assert(sizeof(Vec3d) == 3 * sizeof(double), "Vec3d must be three packed doubles");
  return array_view(reinterpret_cast<const double*>(positions.data()), {positions.size(), 3},
                    std::move(keeper));
}

/// An (n x 3) float64 array of positions [m] as Vec3d; throws ZonaError naming `what` otherwise.
std::vector<Vec3d> to_positions(nb::handle array, const char* what);

/// Adds the run (module_run.cpp) and the readers (module_io.cpp) to the module.
void add_run(nb::module_& m);
void add_io(nb::module_& m);

}  // namespace zona::py
