#include "app.hpp"

int main(int argc, char** argv) { return kscfg::cli::run(argc, argv); }
