// Chooses the compute backend once (STYLE.md habit 6): `--backend auto|cpu|cuda`.
#pragma once

#include <memory>
#include <string>

#include "engine/sim/backend.h"

namespace zona {

/// Creates the backend `kind` asks for:
///  - kCpu: the CPU reference;
///  - kCuda: the CUDA backend, or an error ("built without CUDA", "no usable CUDA device: ...");
///  - kAuto: the CUDA backend when it can be created, else the CPU one, with a one-line reason
///    in `notice` ("no usable CUDA device (...): using the CPU backend").
/// `notice` (optional) is cleared first and only written for kAuto's fallback.
Result<std::unique_ptr<Backend>> make_backend(BackendKind kind, const BackendOptions& options,
                                              std::string* notice = nullptr);

}  // namespace zona
