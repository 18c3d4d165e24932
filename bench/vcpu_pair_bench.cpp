// vcpu_pair_bench: does this machine's second hardware thread add a core's worth of vector
// arithmetic right now? Times a register-only loop of independent fused multiply-adds (ten
// chains, so it is bound by the FMA ports, not by their latency) on one thread, then on two at
// once, and prints the two threads' combined rate over the one thread's rate: ~2 where the two
// threads run on two physical cores, ~1 where they share one (SMT siblings, or a hypervisor that
// placed both vCPUs on one core at that moment). On a cloud VM the answer can change from one
// minute to the next (bench/README.md, "Reading CPU numbers from a shared VM"); run it beside a
// benchmark to tell the machine's state from the code's (bench/repeat_bench.sh, VCPU_PROBE).
// With --stream-kib K each thread instead sweeps a private array of K KiB (a = 0.999 a + b, two
// reads and a write per element; cache-resident for small K): the vCPUs of a shared host can be
// equal for arithmetic and unequal for loads and stores (bench/README.md).
//
//   vcpu_pair_bench [--iterations N] [--rounds R] [--stream-kib K]
//
// One line per round: rate_one rate_two_a rate_two_b pair_scaling, where a rate is FMA
// instructions per ns, or GB/s with --stream-kib.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <thread>
#include <vector>

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#define ZONA_PROBE_X86 1
#endif

namespace {

#ifdef ZONA_PROBE_X86
__attribute__((target("avx2,fma"), noinline)) double fma_chains(long iterations) {
  __m256d a[10];
  for (__m256d& x : a) x = _mm256_set1_pd(1.0);
  const __m256d m = _mm256_set1_pd(0.9999999), c = _mm256_set1_pd(1e-9);
  for (long k = 0; k < iterations; ++k) {
#pragma GCC unroll 10
    for (__m256d& x : a) x = _mm256_fmadd_pd(x, m, c);
  }
  __m256d s = a[0];
  for (int i = 1; i < 10; ++i) s = _mm256_add_pd(s, a[i]);
  double out[4];
  _mm256_storeu_pd(out, s);
  return out[0] + out[1] + out[2] + out[3];
}
#endif

// FMA instructions per nanosecond of one call.
double fma_rate(long iterations) {
  const auto start = std::chrono::steady_clock::now();
#ifdef ZONA_PROBE_X86
  volatile double sink = fma_chains(iterations);
  (void)sink;
#endif
  const double s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return static_cast<double>(iterations) * 10.0 / s / 1e9;
}

// GB/s of `sweeps` sweeps of a = 0.999 a + b over private arrays of `kib` KiB in all.
double stream_rate(long kib, long sweeps) {
  const size_t n = static_cast<size_t>(kib) * 1024 / (2 * sizeof(double));
  std::vector<double> a(n, 1.0), b(n, 1e-9);
  const auto start = std::chrono::steady_clock::now();
  for (long r = 0; r < sweeps; ++r) {
    double* __restrict pa = a.data();
    const double* __restrict pb = b.data();
    for (size_t i = 0; i < n; ++i) pa[i] = 0.999 * pa[i] + pb[i];
    asm volatile("" : : "r"(pa) : "memory");
  }
  const double s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return 3.0 * sizeof(double) * static_cast<double>(n) * static_cast<double>(sweeps) / s / 1e9;
}

long parse_positive(const char* text, const char* flag) {
  char* end = nullptr;
  const long v = std::strtol(text, &end, 10);
  if (end == text || *end != '\0' || v <= 0) {
    std::fprintf(stderr, "vcpu_pair_bench: %s needs a positive integer, got '%s'\n", flag, text);
    std::exit(2);
  }
  return v;
}

}  // namespace

int main(int argc, char** argv) {
  long iterations = 30'000'000;
  long rounds = 4;
  long stream_kib = 0;  // 0: the FMA kernel
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--iterations") == 0 && i + 1 < argc) {
      iterations = parse_positive(argv[++i], "--iterations");
    } else if (std::strcmp(argv[i], "--rounds") == 0 && i + 1 < argc) {
      rounds = parse_positive(argv[++i], "--rounds");
    } else if (std::strcmp(argv[i], "--stream-kib") == 0 && i + 1 < argc) {
      stream_kib = parse_positive(argv[++i], "--stream-kib");
    } else {
      std::fprintf(stderr,
                   "usage: vcpu_pair_bench [--iterations N] [--rounds R] [--stream-kib K]\n");
      return 2;
    }
  }
#ifdef ZONA_PROBE_X86
  __builtin_cpu_init();
  if (!__builtin_cpu_supports("avx2") || !__builtin_cpu_supports("fma")) {
    std::fprintf(stderr, "vcpu_pair_bench: this CPU has no AVX2/FMA; nothing to measure\n");
    return 1;
  }
#else
  std::fprintf(stderr, "vcpu_pair_bench: x86-64 only; nothing to measure\n");
  return 1;
#endif
  // The stream kernel moves ~3 * 8 bytes per FMA instruction of the other; scale its sweeps so
  // that both take a similar time for the same --iterations.
  const long sweeps = std::max(1L, iterations * 10 / std::max(1L, stream_kib * 1024 / 16));
  const auto rate = [&] {
    return stream_kib > 0 ? stream_rate(stream_kib, sweeps) : fma_rate(iterations);
  };
  for (long r = 0; r < rounds; ++r) {
    const double one = rate();
    double two[2] = {0, 0};
    std::thread other([&] { two[1] = rate(); });
    two[0] = rate();
    other.join();
    std::printf("%.3f %.3f %.3f %.3f\n", one, two[0], two[1], (two[0] + two[1]) / one);
    std::fflush(stdout);
  }
  return 0;
}
