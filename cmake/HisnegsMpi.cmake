# SPDX-License-Identifier: Apache-2.0
# Decides whether hisnegs is built with MPI (HISNEGS_MPI = AUTO | ON | OFF): the
# brick fit and the ground truth spread over the ranks of an `mpirun`/`srun`
# launch (apps/pipeline/distributed.hpp). Debian: libopenmpi-dev and openmpi-bin.
# Only MPI's C API is used, through FindMPI's CXX component without the C++
# bindings (MPI_CXX_SKIP_MPICXX: they left the standard); the project has no C.
include(HisnegsOption)
hisnegs_tristate(HISNEGS_MPI "Build with MPI: AUTO (when found), ON or OFF")
set(_hisnegs_mpi ${_HISNEGS_MPI_MODE})
set(HISNEGS_HAVE_MPI OFF)
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
