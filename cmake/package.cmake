# Installation and the Debian package (docs/guide.md, "Install"; CI: .ci/steps/30-deb.sh).
#   cmake -S . -B build-deb -DCMAKE_INSTALL_PREFIX=/usr && cmake --build build-deb -j2
#   cd build-deb && cpack -G DEB         # kscfg_VERSION_ARCH.deb
# Man pages and the changelog are installed compressed (gzip -9n, as Debian policy asks), the
# completions where bash-completion, zsh and fish look, the docs and examples in
# /usr/share/doc/kscfg, the Ansible collection in /usr/share/kscfg/ansible.

set(KSCFG_DOCDIR ${CMAKE_INSTALL_DATADIR}/doc/kscfg)
# zsh on Debian reads /usr/share/zsh/vendor-completions for packages, site-functions under /usr/local.
if(CMAKE_INSTALL_PREFIX STREQUAL "/usr")
  set(KSCFG_ZSH_DIR_DEFAULT ${CMAKE_INSTALL_DATADIR}/zsh/vendor-completions)
else()
  set(KSCFG_ZSH_DIR_DEFAULT ${CMAKE_INSTALL_DATADIR}/zsh/site-functions)
endif()
set(KSCFG_ZSH_COMPLETION_DIR ${KSCFG_ZSH_DIR_DEFAULT} CACHE STRING "Where _kscfg is installed (relative to the prefix)")

# Compressed copies: gzip -9n (best compression, no name or time stamp: reproducible).
find_program(GZIP_EXECUTABLE gzip REQUIRED)
file(GLOB KSCFG_MAN5 CONFIGURE_DEPENDS ${CMAKE_SOURCE_DIR}/man/*.5)
set(KSCFG_GZ_SOURCES ${GEN}/kscfg.1 ${KSCFG_MAN5} ${CMAKE_SOURCE_DIR}/packaging/changelog)
set(KSCFG_GZ_FILES)
foreach(src IN LISTS KSCFG_GZ_SOURCES)
  get_filename_component(name ${src} NAME)
  set(out ${GEN}/gz/${name}.gz)
  add_custom_command(OUTPUT ${out}
    COMMAND ${CMAKE_COMMAND} -E make_directory ${GEN}/gz
    COMMAND ${GZIP_EXECUTABLE} -9n -c ${src} > ${out}
    DEPENDS ${src}
    COMMENT "Compressing ${name}")
  list(APPEND KSCFG_GZ_FILES ${out})
endforeach()
add_custom_target(kscfg_gz ALL DEPENDS ${KSCFG_GZ_FILES})
add_dependencies(kscfg_gz kscfg_docs)

install(TARGETS kscfg RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
install(FILES ${GEN}/gz/kscfg.1.gz DESTINATION ${CMAKE_INSTALL_MANDIR}/man1)
foreach(page IN LISTS KSCFG_MAN5)
  get_filename_component(name ${page} NAME)
  install(FILES ${GEN}/gz/${name}.gz DESTINATION ${CMAKE_INSTALL_MANDIR}/man5)
endforeach()
install(FILES ${GEN}/kscfg.bash DESTINATION ${CMAKE_INSTALL_DATADIR}/bash-completion/completions RENAME kscfg)
install(FILES ${GEN}/_kscfg DESTINATION ${KSCFG_ZSH_COMPLETION_DIR})
install(FILES ${GEN}/kscfg.fish DESTINATION ${CMAKE_INSTALL_DATADIR}/fish/vendor_completions.d)
# The Ansible collection kscfg.bus: ANSIBLE_COLLECTIONS_PATH=/usr/share/kscfg/ansible (docs/guide.md, Fleets).
install(DIRECTORY ${CMAKE_SOURCE_DIR}/contrib/ansible/ansible_collections
        DESTINATION ${CMAKE_INSTALL_DATADIR}/kscfg/ansible
        PATTERN "__pycache__" EXCLUDE PATTERN "*.pyc" EXCLUDE)
# Documentation: /usr/share/doc/kscfg (copyright in Debian's machine-readable format).
install(FILES ${CMAKE_SOURCE_DIR}/packaging/copyright DESTINATION ${KSCFG_DOCDIR})
install(FILES ${GEN}/gz/changelog.gz DESTINATION ${KSCFG_DOCDIR})
install(FILES ${CMAKE_SOURCE_DIR}/README.md ${CMAKE_SOURCE_DIR}/NEWS.md ${CMAKE_SOURCE_DIR}/docs/guide.md
              ${CMAKE_SOURCE_DIR}/docs/performance.md ${CMAKE_SOURCE_DIR}/docs/reliability.md
              ${CMAKE_SOURCE_DIR}/docs/json.md ${CMAKE_SOURCE_DIR}/docs/design.md ${CMAKE_SOURCE_DIR}/catalog/FORMAT.md
        DESTINATION ${KSCFG_DOCDIR})
install(DIRECTORY ${CMAKE_SOURCE_DIR}/examples/ DESTINATION ${KSCFG_DOCDIR}/examples)

# The Debian package. Dependencies come from dpkg-shlibdeps (package dpkg-dev); the binary is
# stripped. Native versioning (no Debian revision), hence changelog.gz rather than changelog.Debian.gz.
set(CPACK_GENERATOR DEB)
set(CPACK_PACKAGE_NAME kscfg)
set(CPACK_PACKAGE_VERSION ${PROJECT_VERSION})
set(CPACK_PACKAGE_CONTACT "kscfg authors <maintainers@users.noreply.h-seed-7fa581a3.example>")
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY "configure Beckhoff-style Bus Terminals through their register interface")
# The long description: CPack puts the summary first and indents each line ("" becomes " .").
set(CPACK_DEBIAN_PACKAGE_DESCRIPTION "kscfg reads and writes the registers of KL/KM Bus Terminals (serial interfaces,
encoders, analog and special terminals) through the control/status byte in a
bus coupler's process image, over Modbus TCP or RTU, like the KS2000 software.
Writes are verified by reading them back and rolled back on failure.

It knows over 160 terminal types by their named parameters (baud rates, frames,
ranges), backs up, compares, applies and restores whole station files, scans
a coupler's layout, and has an emulated station for trying it without
hardware. Output is JSON with --json. Completion for bash, zsh and fish and
an Ansible collection (kscfg.bus) for fleets of couplers are included.")
set(CPACK_DEBIAN_PACKAGE_SECTION electronics)
set(CPACK_DEBIAN_PACKAGE_PRIORITY optional)
set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
set(CPACK_DEBIAN_PACKAGE_SUGGESTS "ansible-core, bash-completion")
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
set(CPACK_STRIP_FILES ON)
set(CPACK_PACKAGING_INSTALL_PREFIX ${CMAKE_INSTALL_PREFIX})
set(CPACK_INSTALL_DEFAULT_DIRECTORY_PERMISSIONS
    OWNER_READ OWNER_WRITE OWNER_EXECUTE GROUP_READ GROUP_EXECUTE WORLD_READ WORLD_EXECUTE)
set(CPACK_SOURCE_GENERATOR "")
include(CPack)
