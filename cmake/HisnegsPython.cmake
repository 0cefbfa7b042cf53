# SPDX-License-Identifier: Apache-2.0
# Decides whether the Python module `hisnegs` is built (HISNEGS_PYTHON = AUTO | ON |
# OFF; apps/python): it needs Python 3 with its headers and NumPy, and pybind11
# (Debian: python3-dev, python3-numpy, pybind11-dev). When it is, every library is
# compiled position-independent, so the static libraries link into the module.
# Debian's /usr/bin/python3 is preferred over another python3 on the PATH (a pyenv
# one lacks Debian's numpy); set Python_EXECUTABLE to choose.
include(HisnegsOption)
hisnegs_tristate(HISNEGS_PYTHON "Build the Python module: AUTO (when pybind11 and NumPy are found), ON or OFF")
set(HISNEGS_HAVE_PYTHON OFF)
if(NOT _HISNEGS_PYTHON_MODE STREQUAL "OFF" AND NOT HISNEGS_FUZZ AND NOT HISNEGS_SANITIZE)
  if(NOT DEFINED Python_EXECUTABLE AND EXISTS /usr/bin/python3)
    set(Python_EXECUTABLE /usr/bin/python3)
  endif()
  find_package(Python 3.9 QUIET COMPONENTS Interpreter Development.Module NumPy)
  if(Python_FOUND AND Python_NumPy_FOUND)
    set(PYBIND11_FINDPYTHON ON)
    find_package(pybind11 2.6 CONFIG QUIET)
  endif()
  if(Python_FOUND AND Python_NumPy_FOUND AND pybind11_FOUND)
    set(HISNEGS_HAVE_PYTHON ON)
  elseif(_HISNEGS_PYTHON_MODE STREQUAL "ON")
    message(FATAL_ERROR "HISNEGS_PYTHON=ON but Python 3 with NumPy (${Python_NumPy_FOUND}) or pybind11 "
                        "(${pybind11_FOUND}) was not found (Debian: python3-dev python3-numpy pybind11-dev)")
  endif()
endif()
if(HISNEGS_HAVE_PYTHON)
  set(CMAKE_POSITION_INDEPENDENT_CODE ON)
  # Where `cmake --install` puts the package: python3's own site folder under the
  # prefix when it has one (Debian, prefix /usr/local: /usr/local/lib/python3.X/
  # dist-packages, on its path), else the prefix's platlib (then on PYTHONPATH).
  set(_hisnegs_find_site [=[
import site, sys, sysconfig
prefix = sys.argv[1].rstrip("/")
inside = [p for p in site.getsitepackages() if p.startswith(prefix + "/")]
print(inside[0] if inside else sysconfig.get_path("platlib", "posix_prefix", vars={"platbase": prefix, "base": prefix}))
]=])
  execute_process(COMMAND "${Python_EXECUTABLE}" -c "${_hisnegs_find_site}" "${CMAKE_INSTALL_PREFIX}"
                  OUTPUT_VARIABLE _hisnegs_platlib OUTPUT_STRIP_TRAILING_WHITESPACE)
  set(HISNEGS_PYTHON_INSTALL_DIR "${_hisnegs_platlib}" CACHE PATH "Where cmake --install puts the hisnegs package")
  message(STATUS "hisnegs: Python module ON (${Python_EXECUTABLE} ${Python_VERSION}, NumPy ${Python_NumPy_VERSION}, "
                 "pybind11 ${pybind11_VERSION}; installs to ${HISNEGS_PYTHON_INSTALL_DIR})")
else()
  message(STATUS "hisnegs: Python module OFF")
endif()
