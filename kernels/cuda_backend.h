// The CUDA backend's constructor. Implemented in cuda_backend.cu, or in cuda_backend_stub.cpp
// (an error value) when zona is built without CUDA; nothing else needs to know which.
#pragma once

#include <memory>

#include "engine/sim/backend.h"

namespace zona {

/// Creates the CUDA backend on options.device. Errors (one line): built without CUDA, no
/// usable device (with the driver's reason), device ordinal out of range.
Result<std::unique_ptr<Backend>> make_cuda_backend(const BackendOptions& options);

}  // namespace zona
