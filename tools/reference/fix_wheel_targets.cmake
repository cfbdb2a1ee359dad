# Injected into every package of the reference build (tools/reference/build.sh) through
# -DCMAKE_PROJECT_INCLUDE. The ROS 2 wheels ship CMake exports written on the machine that built
# them; at the end of the top-level directory (after every find_package) this rewrites them so
# that they link here. No source file of the built packages is changed.
#
#  - include directories that do not exist here (/opt/python/..., a numpy of the wheel builder):
#    CMake's generate step refuses them;
#  - absolute library paths that do not exist here (/usr/lib64/libtinyxml2.so) and OpenSSL::
#    targets (they would pull this machine's OpenSSL next to the wheels' own): the wheels' shared
#    libraries already name their vendored copies;
#  - lttng-ust (there is no liblttng-ust.so to link; libtracetools carries its vendored copy);
#  - *__rosidl_generator_py libraries: C++ code must not link the Python extensions.
cmake_minimum_required(VERSION 3.20)

function(_smbt_filter_list out_var)
  set(kept "")
  foreach(entry IN LISTS ARGN)
    if(entry MATCHES "__rosidl_generator_py" OR entry MATCHES "^OpenSSL::"
       OR entry MATCHES "^(-l)?lttng-ust$")
      continue()
    endif()
    if(entry MATCHES "^/" AND NOT EXISTS "${entry}")
      continue()
    endif()
    list(APPEND kept "${entry}")
  endforeach()
  set(${out_var} "${kept}" PARENT_SCOPE)
endfunction()

function(_smbt_fix_property target property)
  get_target_property(value ${target} ${property})
  if(value)
    _smbt_filter_list(kept ${value})
    set_property(TARGET ${target} PROPERTY ${property} "${kept}")
  endif()
endfunction()

function(_smbt_fix_wheel_targets)
  get_property(imported DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  foreach(target IN LISTS imported)
    _smbt_fix_property(${target} INTERFACE_INCLUDE_DIRECTORIES)
    _smbt_fix_property(${target} INTERFACE_LINK_LIBRARIES)
  endforeach()
  get_property(own DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY BUILDSYSTEM_TARGETS)
  foreach(target IN LISTS own)
    get_target_property(type ${target} TYPE)
    if(NOT type STREQUAL "UTILITY")
      _smbt_fix_property(${target} LINK_LIBRARIES)
      _smbt_fix_property(${target} INTERFACE_LINK_LIBRARIES)
    endif()
  endforeach()
endfunction()

# Included after every project() call: register the rewrite once.
get_property(_smbt_registered GLOBAL PROPERTY SMBT_FIX_WHEEL_TARGETS)
if(NOT _smbt_registered)
  set_property(GLOBAL PROPERTY SMBT_FIX_WHEEL_TARGETS TRUE)
  cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _smbt_fix_wheel_targets)
endif()
