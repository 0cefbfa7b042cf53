# SPDX-License-Identifier: Apache-2.0
# Common flags for every hisnegs target: warnings, unity batches, optional
# sanitizers, fuzzing instrumentation.
option(HISNEGS_UNITY_BUILD "Compile each target's C++ files in unity batches of 6 (faster full builds)" ON)
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
  # Unity batches: header-heavy dependencies (CLI11's inline functions, GoogleTest,
  # Eigen, Ceres, nlohmann-json) are compiled once per batch instead of once per
  # file, which halves a full build on two cores. Files with compile options of
  # their own stay apart (CMake's rule), as do those marked
  # SKIP_UNITY_BUILD_INCLUSION (Highway's per-target re-inclusion). Two files'
  # anonymous-namespace helpers of the same name clash in a batch: rename one.
  set_target_properties(${target} PROPERTIES UNITY_BUILD ${HISNEGS_UNITY_BUILD} UNITY_BUILD_BATCH_SIZE 6)
  if(HISNEGS_UNITY_BUILD AND CMAKE_CXX_COMPILER_ID STREQUAL "GNU")
    # In a batch GCC sees the .cpp files as included headers and warns about their
    # classes holding anonymous-namespace types, which is fine in a .cpp file.
    target_compile_options(${target} PRIVATE $<$<COMPILE_LANGUAGE:CXX>:-Wno-subobject-linkage>)
  endif()
endfunction()
