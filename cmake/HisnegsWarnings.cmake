# SPDX-License-Identifier: Apache-2.0
# Common flags for every hisnegs target: warnings, optional sanitizers, fuzzing instrumentation.
if(HISNEGS_SANITIZE)
  # Global so that every object and every link (tests included) is instrumented.
  add_compile_options($<$<COMPILE_LANGUAGE:CXX>:-fsanitize=address,undefined>
                      $<$<COMPILE_LANGUAGE:CXX>:-fno-omit-frame-pointer>
                      $<$<COMPILE_LANGUAGE:CXX>:-fno-sanitize-recover=undefined>)
  add_link_options(-fsanitize=address,undefined)
endif()
if(HISNEGS_FUZZ)
  # libFuzzer's coverage instrumentation (fuzzer-no-link) on every object; only
  # the fuzz executables link the fuzzer runtime (fuzz/CMakeLists.txt).
  # UBSan aborts on its first report so that libFuzzer records the input.
  if(NOT CMAKE_CXX_COMPILER_ID STREQUAL "Clang")
    message(FATAL_ERROR "HISNEGS_FUZZ needs clang (libFuzzer), got ${CMAKE_CXX_COMPILER_ID}; use the `fuzz` preset")
  endif()
  add_compile_options($<$<COMPILE_LANGUAGE:CXX>:-fsanitize=fuzzer-no-link,address,undefined>
                      $<$<COMPILE_LANGUAGE:CXX>:-fno-omit-frame-pointer>
                      $<$<COMPILE_LANGUAGE:CXX>:-fno-sanitize-recover=undefined>)
  add_link_options(-fsanitize=address,undefined)
endif()

function(hisnegs_target_defaults target)
  # -Wno-restrict: GCC 12 reports false -Wrestrict on plain std::string
  # concatenation at -O2 (GCC bug 105329); other compilers do not need it.
  target_compile_options(${target} PRIVATE
    $<$<COMPILE_LANGUAGE:CXX>:-Wall -Wextra -Wpedantic -Wno-psabi>
    $<$<AND:$<COMPILE_LANGUAGE:CXX>,$<CXX_COMPILER_ID:GNU>>:-Wno-restrict>)
  target_compile_features(${target} PUBLIC cxx_std_20)
endfunction()
