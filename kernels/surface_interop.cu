// The CUDA-Vulkan surface writer (surface_interop.h): import of the renderer's exported memory
// and the two kernels that fill it from the CUDA backend's displacements.
#include <cuda_runtime.h>
#include <unistd.h>

#include <cmath>
#include <cstring>

#include "kernels/cuda_check.h"
#include "kernels/device_buffer.h"
#include "kernels/surface_interop.h"

namespace zona {
namespace {

using cuda::DeviceBuffer;
using cuda::PinnedBuffer;

constexpr int kBlock = 256;
constexpr unsigned kPositiveInfinityBits = 0x7f800000u;

struct PositionParams {
  int n = 0;
  const int* device_index = nullptr;  // compact vertex -> device vertex
  const double* rest = nullptr;       // (3n) [m]
  const double* u = nullptr;          // backend's displacements, device order [length unit]
  double length_unit = 1;
  double3 origin{0, 0, 0};
  double scale = 1;
  int scalar = 0;  // SurfaceScalar
  float4* positions = nullptr;
  unsigned* range = nullptr;  // float bits of the scalar's min and max (non-negative floats)
};

// Positions in render space and the scalar, with the CPU surface pass's operations in the
// same order and rounding (no fused multiply-adds), so that both paths draw the same vertices.
__global__ void write_positions(PositionParams p) {
  const int i = static_cast<int>(blockIdx.x) * kBlock + static_cast<int>(threadIdx.x);
  unsigned lo = kPositiveInfinityBits, hi = 0;
  if (i < p.n) {
    const size_t v = static_cast<size_t>(p.device_index[i]);
    const double ux = __dmul_rn(p.u[3 * v + 0], p.length_unit);
    const double uy = __dmul_rn(p.u[3 * v + 1], p.length_unit);
    const double uz = __dmul_rn(p.u[3 * v + 2], p.length_unit);
    const double x = __dadd_rn(p.rest[3 * i + 0], ux);
    const double y = __dadd_rn(p.rest[3 * i + 1], uy);
    const double z = __dadd_rn(p.rest[3 * i + 2], uz);
    float w = 0.0f;
    if (p.scalar == static_cast<int>(SurfaceScalar::kDisplacement))
      w = static_cast<float>(
          sqrt(__dadd_rn(__dadd_rn(__dmul_rn(ux, ux), __dmul_rn(uy, uy)), __dmul_rn(uz, uz))));
    p.positions[i] = make_float4(static_cast<float>(__dmul_rn(x - p.origin.x, p.scale)),
                                 static_cast<float>(__dmul_rn(y - p.origin.y, p.scale)),
                                 static_cast<float>(__dmul_rn(z - p.origin.z, p.scale)), w);
    if (isfinite(w)) lo = hi = __float_as_uint(w);
  }
  // Non-negative floats order as their bit patterns: one integer min and max per warp.
  lo = __reduce_min_sync(0xffffffffu, lo);
  hi = __reduce_max_sync(0xffffffffu, hi);
  if ((threadIdx.x & 31u) == 0 && lo != kPositiveInfinityBits) {
    atomicMin(&p.range[0], lo);
    atomicMax(&p.range[1], hi);
  }
}

struct NormalParams {
  int n = 0;
  const int* triangle_offsets = nullptr;  // (n + 1), CSR over ascending triangles
  const int* triangles = nullptr;         // triangle indices
  const unsigned* indices = nullptr;      // compact corners, 3 per triangle
  const float4* positions = nullptr;
  float4* normals = nullptr;
};

__device__ float3 corner(const float4* positions, unsigned k) {
  const float4 q = positions[k];
  return make_float3(q.x, q.y, q.z);
}

// Area-weighted vertex normals gathered per vertex in ascending triangle order: the CPU pass
// adds each triangle's cross product to its corners in triangle order, so the sums agree.
__global__ void write_normals(NormalParams p) {
  const int i = static_cast<int>(blockIdx.x) * kBlock + static_cast<int>(threadIdx.x);
  if (i >= p.n) return;
  float sx = 0.0f, sy = 0.0f, sz = 0.0f;
  for (int k = p.triangle_offsets[i]; k < p.triangle_offsets[i + 1]; ++k) {
    const size_t t = static_cast<size_t>(p.triangles[k]);
    const float3 a = corner(p.positions, p.indices[3 * t]);
    const float3 b = corner(p.positions, p.indices[3 * t + 1]);
    const float3 c = corner(p.positions, p.indices[3 * t + 2]);
    const float3 e = make_float3(__fsub_rn(b.x, a.x), __fsub_rn(b.y, a.y), __fsub_rn(b.z, a.z));
    const float3 f = make_float3(__fsub_rn(c.x, a.x), __fsub_rn(c.y, a.y), __fsub_rn(c.z, a.z));
    sx = __fadd_rn(sx, __fsub_rn(__fmul_rn(e.y, f.z), __fmul_rn(f.y, e.z)));
    sy = __fadd_rn(sy, __fsub_rn(__fmul_rn(e.z, f.x), __fmul_rn(f.z, e.x)));
    sz = __fadd_rn(sz, __fsub_rn(__fmul_rn(e.x, f.y), __fmul_rn(f.x, e.y)));
  }
  const float len =
      sqrtf(__fadd_rn(__fadd_rn(__fmul_rn(sx, sx), __fmul_rn(sy, sy)), __fmul_rn(sz, sz)));
  p.normals[i] = len > 0.0f ? make_float4(__fdiv_rn(sx, len), __fdiv_rn(sy, len),
                                          __fdiv_rn(sz, len), 0.0f)
                            : make_float4(0.0f, 0.0f, 1.0f, 0.0f);
}

unsigned blocks_for(int n) {
  return static_cast<unsigned>((n + kBlock - 1) / kBlock);
}

class CudaSurfaceWriter final : public SurfaceWriter {
 public:
  ~CudaSurfaceWriter() override {
    if (mapped_) (void)cudaFree(mapped_);
    if (memory_) (void)cudaDestroyExternalMemory(memory_);
    if (fd_ >= 0) ::close(fd_);
  }

  Status init(const Backend& backend, const Model& model, const SharedSurfaceTarget& target) {
    fd_ = target.memory_fd;  // owned from here on, whatever happens
    const DeviceStateView view = backend.device_state();
    if (!view.u)
      return make_error("interop: the %s backend keeps no state on a GPU (the copy path is used)",
                        backend.name());
    device_ = view.device;
    ZONA_CUDA_TRY(cudaSetDevice(device_));
    cudaDeviceProp prop{};
    ZONA_CUDA_TRY(cudaGetDeviceProperties(&prop, device_));
    if (std::memcmp(prop.uuid.bytes, target.device_uuid.data(), 16) != 0)
      return make_error(
          "interop: the Vulkan device is not CUDA device %d (%s): UUIDs differ (choose the same "
          "GPU with ZONA_VK_DEVICE)",
          device_, prop.name);
    const size_t n = target.mesh_vertex.size();
    const size_t nt = target.indices.size() / 3;
    if (target.indices.size() % 3 != 0)
      return make_error("interop: %zu triangle indices is not a multiple of 3",
                        target.indices.size());
    if (target.positions_offset + n * sizeof(float4) > target.memory_bytes ||
        target.normals_offset + n * sizeof(float4) > target.memory_bytes)
      return make_error("interop: %zu surface vertices do not fit the %llu-byte shared memory", n,
                        static_cast<unsigned long long>(target.memory_bytes));
    const size_t nv = model.vertex_count();
    std::vector<int> device_index(n);
    std::vector<double> rest(3 * n);
    for (size_t i = 0; i < n; ++i) {
      const int32_t v = target.mesh_vertex[i];
      if (v < 0 || static_cast<size_t>(v) >= nv || view.vertex_old_to_new.size() != nv)
        return make_error("interop: surface vertex %zu is mesh vertex %d, the model has %zu", i, v,
                          nv);
      device_index[i] = view.vertex_old_to_new[static_cast<size_t>(v)];
      const Vec3d x = model.rest_positions[static_cast<size_t>(v)];
      rest[3 * i] = x.x;
      rest[3 * i + 1] = x.y;
      rest[3 * i + 2] = x.z;
    }
    // Vertex -> triangles (CSR, ascending triangle order within each vertex).
    std::vector<int> offsets(n + 1, 0), triangles(3 * nt);
    for (uint32_t k : target.indices) {
      if (k >= n)
        return make_error("interop: triangle corner %u out of range (%zu surface vertices)", k, n);
      ++offsets[k + 1];
    }
    for (size_t i = 0; i < n; ++i) offsets[i + 1] += offsets[i];
    std::vector<int> fill(offsets.begin(), offsets.end() - 1);
    for (size_t t = 0; t < nt; ++t)
      for (int c = 0; c < 3; ++c) triangles[static_cast<size_t>(fill[target.indices[3 * t + c]]++)] =
          static_cast<int>(t);

    cudaExternalMemoryHandleDesc desc{};
    desc.type = cudaExternalMemoryHandleTypeOpaqueFd;
    desc.handle.fd = fd_;
    desc.size = target.memory_bytes;
    desc.flags = cudaExternalMemoryDedicated;  // the renderer allocates it dedicated
    ZONA_CUDA_TRY(cudaImportExternalMemory(&memory_, &desc));
    fd_ = -1;  // CUDA owns the descriptor after a successful import
    cudaExternalMemoryBufferDesc buffer{};
    buffer.offset = 0;
    buffer.size = target.memory_bytes;
    ZONA_CUDA_TRY(cudaExternalMemoryGetMappedBuffer(&mapped_, memory_, &buffer));
    positions_ = reinterpret_cast<float4*>(static_cast<char*>(mapped_) + target.positions_offset);
    normals_ = reinterpret_cast<float4*>(static_cast<char*>(mapped_) + target.normals_offset);

    n_ = n;
    if (Status s = d_device_index_.upload(device_index, "interop vertex map"); !s) return s;
    if (Status s = d_rest_.upload(rest, "interop rest positions"); !s) return s;
    if (Status s = d_offsets_.upload(offsets, "interop triangle offsets"); !s) return s;
    if (Status s = d_triangles_.upload(triangles, "interop triangle lists"); !s) return s;
    std::vector<unsigned> indices(target.indices.begin(), target.indices.end());
    if (Status s = d_indices_.upload(indices, "interop triangles"); !s) return s;
    if (Status s = d_range_.allocate(2, "interop scalar range"); !s) return s;
    if (Status s = h_range_.allocate(2, "interop scalar range"); !s) return s;
    backend_ = &backend;
    return {};
  }

  Result<SurfaceWriteResult> write(const Backend& backend, Vec3d origin, double scale,
                                   SurfaceScalar scalar) override {
    const DeviceStateView view = backend.device_state();
    if (&backend != backend_ || !view.u)
      return make_error("interop: not the backend this writer was made for");
    SurfaceWriteResult result;
    if (n_ == 0) return result;
    ZONA_CUDA_TRY(cudaSetDevice(device_));
    auto stream = static_cast<cudaStream_t>(view.stream);
    const unsigned init[2] = {kPositiveInfinityBits, 0u};
    h_range_[0] = init[0];
    h_range_[1] = init[1];
    ZONA_CUDA_TRY(cudaMemcpyAsync(d_range_.data(), h_range_.data(), 2 * sizeof(unsigned),
                                  cudaMemcpyHostToDevice, stream));
    PositionParams pp;
    pp.n = static_cast<int>(n_);
    pp.device_index = d_device_index_.data();
    pp.rest = d_rest_.data();
    pp.u = view.u;
    pp.length_unit = view.length_unit;
    pp.origin = make_double3(origin.x, origin.y, origin.z);
    pp.scale = scale;
    pp.scalar = static_cast<int>(scalar);
    pp.positions = positions_;
    pp.range = d_range_.data();
    write_positions<<<blocks_for(pp.n), kBlock, 0, stream>>>(pp);
    ZONA_CUDA_TRY_LAUNCH();
    NormalParams np;
    np.n = pp.n;
    np.triangle_offsets = d_offsets_.data();
    np.triangles = d_triangles_.data();
    np.indices = d_indices_.data();
    np.positions = positions_;
    np.normals = normals_;
    write_normals<<<blocks_for(np.n), kBlock, 0, stream>>>(np);
    ZONA_CUDA_TRY_LAUNCH();
    ZONA_CUDA_TRY(cudaMemcpyAsync(h_range_.data(), d_range_.data(), 2 * sizeof(unsigned),
                                  cudaMemcpyDeviceToHost, stream));
    ZONA_CUDA_TRY(cudaStreamSynchronize(stream));
    float lo = 0, hi = 0;
    std::memcpy(&lo, &h_range_[0], sizeof(float));
    std::memcpy(&hi, &h_range_[1], sizeof(float));
    if (h_range_[0] != kPositiveInfinityBits) {
      result.scalar_min = lo;
      result.scalar_max = hi;
    }
    return result;
  }

  Status read_back(std::vector<std::array<float, 4>>* positions,
                   std::vector<std::array<float, 4>>* normals) override {
    ZONA_CUDA_TRY(cudaSetDevice(device_));
    positions->resize(n_);
    normals->resize(n_);
    if (n_ == 0) return {};
    ZONA_CUDA_TRY(
        cudaMemcpy(positions->data(), positions_, n_ * sizeof(float4), cudaMemcpyDeviceToHost));
    ZONA_CUDA_TRY(
        cudaMemcpy(normals->data(), normals_, n_ * sizeof(float4), cudaMemcpyDeviceToHost));
    return {};
  }

  size_t vertex_count() const override { return n_; }

 private:
  int fd_ = -1;
  int device_ = 0;
  cudaExternalMemory_t memory_ = nullptr;
  void* mapped_ = nullptr;
  float4* positions_ = nullptr;
  float4* normals_ = nullptr;
  size_t n_ = 0;
  const Backend* backend_ = nullptr;  // the backend whose state is written
  DeviceBuffer<int> d_device_index_, d_offsets_, d_triangles_;
  DeviceBuffer<double> d_rest_;
  DeviceBuffer<unsigned> d_indices_, d_range_;
  PinnedBuffer<unsigned> h_range_;
};

}  // namespace

Result<std::unique_ptr<SurfaceWriter>> make_surface_writer(const Backend& backend,
                                                           const Model& model,
                                                           const SharedSurfaceTarget& target) {
  auto writer = std::make_unique<CudaSurfaceWriter>();
  if (Status s = writer->init(backend, model, target); !s) return s.error();
  return std::unique_ptr<SurfaceWriter>(std::move(writer));
}

}  // namespace zona
