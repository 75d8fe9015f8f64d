// Minimal stand-in for <gloo/transport/device.h> (see ../algorithm.h).
#pragma once
namespace gloo {
namespace transport {
class Device;
class UnboundBuffer;
} // namespace transport
} // namespace gloo
