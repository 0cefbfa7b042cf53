# SPDX-License-Identifier: Apache-2.0
# hisnegs_tristate(NAME DOC): an AUTO | ON | OFF cache option (default AUTO) and
# _NAME_MODE in the caller's scope, its value upper-cased; any other value stops
# the configure with one line. The optional parts (CUDA, MPI, Python) use it.
function(hisnegs_tristate name doc)
  set(${name} AUTO CACHE STRING "${doc}")
  set_property(CACHE ${name} PROPERTY STRINGS AUTO ON OFF)
  string(TOUPPER "${${name}}" mode)
  if(NOT mode MATCHES "^(AUTO|ON|OFF)$")
    message(FATAL_ERROR "${name} must be AUTO, ON or OFF, got '${${name}}'")
  endif()
  set(_${name}_MODE ${mode} PARENT_SCOPE)
endfunction()
