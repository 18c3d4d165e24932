// Small fixed-size 3-vectors and 3x3 matrices usable on the CPU and in CUDA kernels.
//
// Why not Eigen or GLM here: the per-element functions must compile under nvcc for the device,
// in float and double, with no hidden alignment or temporaries; a hundred lines of plain
// structs keep the generated code predictable. Eigen stays in host-only code (solvers, tests).
#pragma once

#include <cmath>

#include "engine/core/base.h"

namespace zona {

template <class T>
struct Vec3 {
  T x, y, z;
  ZONA_HOST_DEVICE constexpr T& operator[](int i) { return i == 0 ? x : (i == 1 ? y : z); }
  ZONA_HOST_DEVICE constexpr const T& operator[](int i) const {
    return i == 0 ? x : (i == 1 ? y : z);
  }
};

using Vec3d = Vec3<double>;
using Vec3f = Vec3<float>;

template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Vec3<T> operator+(Vec3<T> a, Vec3<T> b) {
  return {a.x + b.x, a.y + b.y, a.z + b.z};
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Vec3<T> operator-(Vec3<T> a, Vec3<T> b) {
  return {a.x - b.x, a.y - b.y, a.z - b.z};
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Vec3<T> operator-(Vec3<T> a) {
  return {-a.x, -a.y, -a.z};
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Vec3<T> operator*(T s, Vec3<T> a) {
  return {s * a.x, s * a.y, s * a.z};
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Vec3<T> operator*(Vec3<T> a, T s) {
  return {s * a.x, s * a.y, s * a.z};
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Vec3<T> operator/(Vec3<T> a, T s) {
  return {a.x / s, a.y / s, a.z / s};
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Vec3<T>& operator+=(Vec3<T>& a, Vec3<T> b) {
  a.x += b.x; a.y += b.y; a.z += b.z;
  return a;
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Vec3<T>& operator-=(Vec3<T>& a, Vec3<T> b) {
  a.x -= b.x; a.y -= b.y; a.z -= b.z;
  return a;
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr T dot(Vec3<T> a, Vec3<T> b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Vec3<T> cross(Vec3<T> a, Vec3<T> b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE T norm(Vec3<T> a) {
  return std::sqrt(dot(a, a));
}
template <class To, class From>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Vec3<To> vec_cast(Vec3<From> a) {
  return {static_cast<To>(a.x), static_cast<To>(a.y), static_cast<To>(a.z)};
}

/// 3x3 matrix, row-major: m[r][c].
template <class T>
struct Mat3 {
  T m[3][3];
  ZONA_HOST_DEVICE static constexpr Mat3 zero() { return {{{0, 0, 0}, {0, 0, 0}, {0, 0, 0}}}; }
  ZONA_HOST_DEVICE static constexpr Mat3 identity() {
    return {{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};
  }
  ZONA_HOST_DEVICE constexpr T& operator()(int r, int c) { return m[r][c]; }
  ZONA_HOST_DEVICE constexpr const T& operator()(int r, int c) const { return m[r][c]; }
};

using Mat3d = Mat3<double>;
using Mat3f = Mat3<float>;

template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Vec3<T> operator*(const Mat3<T>& a, Vec3<T> v) {
  return {a.m[0][0] * v.x + a.m[0][1] * v.y + a.m[0][2] * v.z,
          a.m[1][0] * v.x + a.m[1][1] * v.y + a.m[1][2] * v.z,
          a.m[2][0] * v.x + a.m[2][1] * v.y + a.m[2][2] * v.z};
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Mat3<T> operator*(const Mat3<T>& a, const Mat3<T>& b) {
  Mat3<T> c{};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      c.m[i][j] = a.m[i][0] * b.m[0][j] + a.m[i][1] * b.m[1][j] + a.m[i][2] * b.m[2][j];
  return c;
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Mat3<T> transpose(const Mat3<T>& a) {
  Mat3<T> t{};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) t.m[i][j] = a.m[j][i];
  return t;
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr T trace(const Mat3<T>& a) {
  return a.m[0][0] + a.m[1][1] + a.m[2][2];
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr T determinant(const Mat3<T>& a) {
  return a.m[0][0] * (a.m[1][1] * a.m[2][2] - a.m[1][2] * a.m[2][1]) -
         a.m[0][1] * (a.m[1][0] * a.m[2][2] - a.m[1][2] * a.m[2][0]) +
         a.m[0][2] * (a.m[1][0] * a.m[2][1] - a.m[1][1] * a.m[2][0]);
}
/// Outer product a b^T.
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Mat3<T> outer(Vec3<T> a, Vec3<T> b) {
  return {{{a.x * b.x, a.x * b.y, a.x * b.z},
           {a.y * b.x, a.y * b.y, a.y * b.z},
           {a.z * b.x, a.z * b.y, a.z * b.z}}};
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Mat3<T> operator+(const Mat3<T>& a, const Mat3<T>& b) {
  Mat3<T> c{};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) c.m[i][j] = a.m[i][j] + b.m[i][j];
  return c;
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Mat3<T> operator-(const Mat3<T>& a, const Mat3<T>& b) {
  Mat3<T> c{};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) c.m[i][j] = a.m[i][j] - b.m[i][j];
  return c;
}
template <class T>
ZONA_HOST_DEVICE ZONA_INLINE constexpr Mat3<T> operator*(T s, const Mat3<T>& a) {
  Mat3<T> c{};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) c.m[i][j] = s * a.m[i][j];
  return c;
}

}  // namespace zona
