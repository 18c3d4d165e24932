# Finds the Python interpreter with its headers and nanobind (`python -m nanobind --cmake_dir`),
# setting ZONA_HAVE_PYTHON. Quiet when either is missing: the module is optional.
find_package(Python 3.9 COMPONENTS Interpreter Development.Module QUIET)
if(Python_FOUND)
  execute_process(COMMAND "${Python_EXECUTABLE}" -m nanobind --cmake_dir
                  OUTPUT_VARIABLE ZONA_NANOBIND_DIR OUTPUT_STRIP_TRAILING_WHITESPACE
                  RESULT_VARIABLE ZONA_NANOBIND_RC ERROR_QUIET)
  if(ZONA_NANOBIND_RC EQUAL 0 AND IS_DIRECTORY "${ZONA_NANOBIND_DIR}")
    find_package(nanobind CONFIG QUIET PATHS "${ZONA_NANOBIND_DIR}" NO_DEFAULT_PATH)
  endif()
endif()
if(Python_FOUND AND nanobind_FOUND)
  set(ZONA_HAVE_PYTHON ON)
else()
  message(STATUS "zona: no Python module: ${Python_EXECUTABLE} has no nanobind or no headers "
                 "(bash scripts/setup.sh makes .venv; configure with "
                 "-DPython_EXECUTABLE=.venv/bin/python)")
endif()
