# The registry's wheels export include directories of the machine they were built on; drop
# those that do not exist here from every imported target (a no-op on a real ROS install).
# Included after rosidl_generate_interfaces by each stand-in.
get_property(targets DIRECTORY PROPERTY IMPORTED_TARGETS)
foreach(target ${targets})
  get_target_property(dirs ${target} INTERFACE_INCLUDE_DIRECTORIES)
  if(dirs)
    set(kept "")
    foreach(dir ${dirs})
      if(EXISTS "${dir}" OR dir MATCHES "^\\$<")
        list(APPEND kept "${dir}")
      endif()
    endforeach()
    set_target_properties(${target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${kept}")
  endif()
endforeach()
