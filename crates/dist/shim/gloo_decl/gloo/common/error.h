// Minimal stand-in for <gloo/common/error.h> (see ../algorithm.h).
#pragma once
