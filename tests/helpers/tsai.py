"""ASP ``.tsai`` pinhole text for tests: a camera 100 km above (R, 0, 0) of the Moon,
looking down −X; image right = +Y, image down = −Z; f 20 mm, 10 µm pixels (2000 px),
principal point 5.12 mm (512 px) from the corner."""

#: the VERSION_4 PINHOLE keys, up to ``pitch`` (the lens section follows)
HEADER = """VERSION_4
PINHOLE
fu = 20
fv = 20
cu = 5.12
cv = 5.12
u_direction = 1 0 0
v_direction = 0 1 0
w_direction = 0 0 1
C = 1837400 0 0
R = 0 0 -1 1 0 0 0 -1 0
pitch = 0.01
"""
#: the whole file with an ideal lens (ASP's ``NULL``)
NULL_LENS = HEADER + "NULL\n"
