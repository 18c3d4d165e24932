# Writes the source tree's HEAD commit into OUT as ZONA_BUILD_COMMIT, at every build, touching the
# file only when the text changes (so an unchanged commit rebuilds nothing). "+dirty" marks a
# tree with uncommitted changes to tracked files; empty without git or outside a repository.
execute_process(COMMAND git -C "${SRC}" rev-parse --short=12 HEAD
                OUTPUT_VARIABLE commit OUTPUT_STRIP_TRAILING_WHITESPACE
                RESULT_VARIABLE rc ERROR_QUIET)
if(NOT rc EQUAL 0)
  set(commit "")
else()
  execute_process(COMMAND git -C "${SRC}" status --porcelain --untracked-files=no
                  OUTPUT_VARIABLE dirty OUTPUT_STRIP_TRAILING_WHITESPACE ERROR_QUIET)
  if(NOT "${dirty}" STREQUAL "")
    set(commit "${commit}+dirty")
  endif()
endif()
set(text "#define ZONA_BUILD_COMMIT \"${commit}\"\n")
set(old "")
if(EXISTS "${OUT}")
  file(READ "${OUT}" old)
endif()
if(NOT "${old}" STREQUAL "${text}")
  file(WRITE "${OUT}" "${text}")
endif()
