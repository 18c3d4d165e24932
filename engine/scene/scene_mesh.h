// The mesh a scene asks for: read from its file or generated, with the needle's entry point.
#pragma once

#include <string>
#include <vector>

#include "engine/core/base.h"
#include "engine/mesh/mesh.h"
#include "engine/mesh/mesh_generate.h"
#include "engine/scene/scene.h"

namespace zona {

/// Where the needle axis first meets the undeformed cell surface [m]. For a generated ball the
/// intersection is exact; with no explicit start the needle is aimed at the cell centre along
/// needle.direction, so the entry point is -direction * radius.
Vec3d needle_entry_point(const Scene& scene);

/// The generator spec for a scene's `mesh.generate` section ("refine_at": "needle" resolved).
CellMeshSpec cell_mesh_spec(const Scene& scene);

/// Builds the scene's mesh: reads `mesh.file` (scaled by its unit) or runs the generator.
/// Warnings from the reader (repaired orientation, ...) are appended when `warnings` is given.
Result<Mesh> build_scene_mesh(const Scene& scene, std::vector<std::string>* warnings = nullptr);

}  // namespace zona
