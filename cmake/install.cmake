# Installation: `cmake --install BUILD [--prefix P]` puts the shared library, the public headers,
# the CMake package (find_package(adaptiso 0.2) → adaptiso::adaptiso), a pkg-config file, the
# command line with its viewer page, and (with ADAPTISO_BUILD_PYTHON) the Python module.
include(CMakePackageConfigHelpers)

install(TARGETS adaptiso_shared EXPORT adaptisoTargets
        LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}
        ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR})
install(DIRECTORY ${PROJECT_SOURCE_DIR}/include/adaptiso DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}
        FILES_MATCHING PATTERN "*.hpp" PATTERN "view_server.hpp" EXCLUDE)
install(FILES ${PROJECT_BINARY_DIR}/include/adaptiso/version.hpp DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/adaptiso)

set(ADAPTISO_CMAKE_DIR ${CMAKE_INSTALL_LIBDIR}/cmake/adaptiso)
install(EXPORT adaptisoTargets NAMESPACE adaptiso:: DESTINATION ${ADAPTISO_CMAKE_DIR})
configure_package_config_file(${PROJECT_SOURCE_DIR}/cmake/adaptisoConfig.cmake.in ${PROJECT_BINARY_DIR}/adaptisoConfig.cmake
                              INSTALL_DESTINATION ${ADAPTISO_CMAKE_DIR})
write_basic_package_version_file(${PROJECT_BINARY_DIR}/adaptisoConfigVersion.cmake COMPATIBILITY SameMinorVersion)
install(FILES ${PROJECT_BINARY_DIR}/adaptisoConfig.cmake ${PROJECT_BINARY_DIR}/adaptisoConfigVersion.cmake DESTINATION ${ADAPTISO_CMAKE_DIR})

# Relative to the .pc file, so the tree can be installed under any --prefix.
file(RELATIVE_PATH ADAPTISO_PC_TO_PREFIX /p/${CMAKE_INSTALL_LIBDIR}/pkgconfig /p)
configure_file(${PROJECT_SOURCE_DIR}/cmake/adaptiso.pc.in ${PROJECT_BINARY_DIR}/adaptiso.pc @ONLY)
install(FILES ${PROJECT_BINARY_DIR}/adaptiso.pc DESTINATION ${CMAKE_INSTALL_LIBDIR}/pkgconfig)

if(ADAPTISO_BUILD_APPS)
  install(TARGETS adaptiso_cli RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
  # The page's files (web/served.txt), where `adaptiso view` looks for them: ../share/adaptiso/web
  # beside its own folder.
  # served.txt itself goes too: the server serves nothing that it does not list (without it the
  # installed page was index.html alone, every script and style answered 404).
  install(FILES ${PROJECT_SOURCE_DIR}/web/served.txt DESTINATION ${CMAKE_INSTALL_DATADIR}/adaptiso/web)
  file(STRINGS ${PROJECT_SOURCE_DIR}/web/served.txt ADAPTISO_WEB_FILES REGEX "^[^#]")
  foreach(f IN LISTS ADAPTISO_WEB_FILES)
    get_filename_component(dir ${f} DIRECTORY)
    install(FILES ${PROJECT_SOURCE_DIR}/web/${f} DESTINATION ${CMAKE_INSTALL_DATADIR}/adaptiso/web/${dir} OPTIONAL)
    # The npm packages (three.js, meshoptimizer's decoder) come from scripts/deps.sh; a tree
    # installed without them has a viewer page that cannot start, which is said at install time.
    install(CODE "if(NOT EXISTS \"${PROJECT_SOURCE_DIR}/web/${f}\")
  message(WARNING \"web/${f} is missing (run scripts/deps.sh): the installed viewer page will not load\")
endif()")
  endforeach()
endif()
