"""Comparing impressions (Qt-free): two surfaces registered, their signed difference, mean tracks.

- :mod:`.surfaces` - a surface from a reconstruction folder, an X3P or a PLY, as a height grid
  in the right-handed export frame (mm);
- :mod:`.register` - coarse registration (point pairs, or principal axes with a search over the
  180 degree ambiguity) refined by open3d point-to-plane ICP with a robust kernel;
- :mod:`.difference` - B resampled onto A's grid through the registration, the signed
  difference A - B (mm), its histogram and the regions beyond a threshold;
- :mod:`.mean` - a mean track (mean, standard deviation and count per cell) of registered maps;
- :mod:`.record` - ``impress compare``: every file of a comparison written atomically with its
  JSON record (inputs' SHA-256, parameters, registration, residuals) and an HTML report.
"""
