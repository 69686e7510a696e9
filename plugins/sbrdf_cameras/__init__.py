"""Camera devices: the virtual gonioreflectometer camera."""
