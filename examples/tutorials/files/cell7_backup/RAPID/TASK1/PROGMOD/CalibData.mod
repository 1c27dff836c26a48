MODULE CalibData
  PERS tooldata tGun:=[TRUE,[[0,0,150],[0.9659258,0,0.258819,0]],[1.5,[0,0,50],[1,0,0,0],0,0,0]];
  TASK PERS wobjdata wFixture:=[FALSE,TRUE,"",[[400,-100,50],[0.9238795,0,0,0.3826834]],[[10,20,0],[1,0,0,0]]];
ENDMODULE
