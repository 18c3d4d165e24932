// Allocations made by this test binary so far (tests/engine/sim/job_test.cpp replaces the global
// operator new to count them): the step paths must make none. -1 where the count is not
// available (sanitizer builds, which own operator new).
#pragma once

namespace zona::test {
long long allocation_count();
}  // namespace zona::test
