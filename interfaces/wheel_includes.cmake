# Loaded into each interface package with -DCMAKE_PROJECT_INCLUDE (see README.md here).
# The PyPI message wheels' imported CMake targets carry the wheel builder's include path
# (/opt/python/cp311-cp311/include/python3.11), which does not exist here and makes CMake's
# generate step fail. At the end of the package's CMakeLists.txt, drop every include directory
# of an imported target that does not exist.
function(_rls_drop_missing_include_directories)
  get_property(_targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  foreach(_target IN LISTS _targets)
    get_target_property(_directories ${_target} INTERFACE_INCLUDE_DIRECTORIES)
    if(_directories)
      set(_kept "")
      foreach(_directory IN LISTS _directories)
        if(_directory MATCHES "^\\$<" OR EXISTS "${_directory}")
          list(APPEND _kept "${_directory}")
        endif()
      endforeach()
      set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_kept}")
    endif()
  endforeach()
endfunction()
cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _rls_drop_missing_include_directories)
