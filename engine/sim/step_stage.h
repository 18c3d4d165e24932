// The injection step's stages, in the order one step runs them: one name for the code (the CPU
// runner's step_once, the CUDA runner's enqueue_step), the kernels and the docs
// (docs/architecture.md, "One step").
#pragma once

#include <cstdint>

namespace zona {

/// One stage of the step. Each line of CpuJobRunner::step_once is one of these; the CUDA
/// runner's kernels say which they run.
enum class StepStage : int32_t {
  kMasses = 0,  ///< dynamic mass scaling: raise the corner masses of stiffened elements
  kLoads,       ///< stiffness damping and drift damping loads
  kTools,       ///< tool terms' forces: needle (faces or vertices), rim with friction, suction
  kElastic,     ///< elastic term's forces (the element pass; nodal pressure's two passes)
  kIntegrate,   ///< centred difference to u_{n+1}
  kMeasure,     ///< tools' work, energies, deformation at the entry point, drift momentum
  kRecord,      ///< measures into the record, health, force filter, local stiffness, quasi-static
  kCommit,      ///< what carries over: friction anchors, release, the next tool pose
  kPuncture,    ///< the puncture test on a healthy, quasi-static state
  kCount
};

}  // namespace zona
