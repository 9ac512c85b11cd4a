"""Map-side models: terrain, landmarks, camera emulator, viewframes, symbolic
descriptions, associative memory and landmark detectors."""
