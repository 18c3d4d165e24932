// Two boxes sharing the face x = 1: "left" [0,1]^3 (tag 11) and "right" [1,3]x[0,1]^2 (tag 12).
SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, 1, 1, 1};
Box(2) = {1, 0, 0, 2, 1, 1};
BooleanFragments{ Volume{1}; Delete; }{ Volume{2}; Delete; }
// A free point outside the volumes: its node must be dropped by the reader.
Point(100) = {5, 5, 5, 1.0};
Physical Volume("left", 11) = {1};
Physical Volume("right", 12) = {2};
Physical Surface("outer_x0", 21) = {1};
Physical Point("marker", 31) = {100};
Mesh.CharacteristicLengthMax = 0.5;
Mesh.CharacteristicLengthMin = 0.5;
