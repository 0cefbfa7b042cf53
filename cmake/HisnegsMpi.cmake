# SPDX-License-Identifier: Apache-2.0
# Decides whether hisnegs is built with MPI (HISNEGS_MPI = AUTO | ON | OFF): the
# brick fit and the ground truth spread over the ranks of an `mpirun`/`srun`
# launch (apps/pipeline/distributed.hpp). Debian: libopenmpi-dev and openmpi-bin.
# Only MPI's C API is used, through FindMPI's CXX component without the C++
# bindings (MPI_CXX_SKIP_MPICXX: they left the standard); the project has no C.
set(HISNEGS_MPI AUTO CACHE STRING "Build with MPI: AUTO (when found), ON or OFF")
set_property(CACHE HISNEGS_MPI PROPERTY STRINGS AUTO ON OFF)
set(HISNEGS_HAVE_MPI OFF)
string(TOUPPER "${HISNEGS_MPI}" _hisnegs_mpi)
if(NOT _hisnegs_mpi MATCHES "^(AUTO|ON|OFF)$")
  message(FATAL_ERROR "HISNEGS_MPI must be AUTO, ON or OFF, got '${HISNEGS_MPI}'")
endif()
if(NOT _hisnegs_mpi STREQUAL "OFF")
  set(MPI_CXX_SKIP_MPICXX ON)
  if(_hisnegs_mpi STREQUAL "ON")
    find_package(MPI REQUIRED COMPONENTS CXX)
  else()
    find_package(MPI QUIET COMPONENTS CXX)
  endif()
  if(MPI_CXX_FOUND)
    set(HISNEGS_HAVE_MPI ON)
  endif()
endif()
if(HISNEGS_HAVE_MPI)
  message(STATUS "hisnegs: MPI ON (MPI ${MPI_CXX_VERSION}; tests launch ${MPIEXEC_EXECUTABLE})")
else()
  message(STATUS "hisnegs: MPI OFF")
endif()
