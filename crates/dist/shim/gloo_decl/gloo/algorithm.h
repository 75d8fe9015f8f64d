// Minimal stand-in for Gloo's <gloo/algorithm.h>: libtorch's wheel ships
// ProcessGroupGloo.hpp but not the Gloo headers it includes. The shim only
// uses ProcessGroupGloo through its out-of-line (library) functions, which
// handle every Gloo object behind a pointer, so declarations suffice.
#pragma once
#include "context.h"
