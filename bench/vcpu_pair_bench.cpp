// vcpu_pair_bench: does this machine's second hardware thread add a core's worth of vector
// arithmetic right now? Times a register-only loop of independent fused multiply-adds (ten
// chains, so it is bound by the FMA ports, not by their latency) on one thread, then on two at
// once, and prints the two threads' combined rate over the one thread's rate: ~2 where the two
// threads run on two physical cores, ~1 where they share one (SMT siblings, or a hypervisor that
// placed both vCPUs on one core at that moment). On a cloud VM the answer can change from one
// minute to the next (bench/README.md, docs/performance.md "Seventh round"); run it beside a
// benchmark to tell the machine's state from the code's (bench/repeat_bench.sh, VCPU_PROBE).
//
//   vcpu_pair_bench [--iterations N] [--rounds R]
//
// One line per round: fma_per_ns_one fma_per_ns_two_a fma_per_ns_two_b pair_scaling.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <thread>

namespace {

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#define ZONA_PROBE_X86 1
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
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--iterations") == 0 && i + 1 < argc) {
      iterations = parse_positive(argv[++i], "--iterations");
    } else if (std::strcmp(argv[i], "--rounds") == 0 && i + 1 < argc) {
      rounds = parse_positive(argv[++i], "--rounds");
    } else {
      std::fprintf(stderr, "usage: vcpu_pair_bench [--iterations N] [--rounds R]\n");
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
  for (long r = 0; r < rounds; ++r) {
    const double one = fma_rate(iterations);
    double two[2] = {0, 0};
    std::thread other([&] { two[1] = fma_rate(iterations); });
    two[0] = fma_rate(iterations);
    other.join();
    std::printf("%.3f %.3f %.3f %.3f\n", one, two[0], two[1], (two[0] + two[1]) / one);
    std::fflush(stdout);
  }
  return 0;
}
