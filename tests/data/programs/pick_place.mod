%%%
  VERSION:1
  LANGUAGE:ENGLISH
%%%

MODULE PickPlace
  ! Pick-and-place cell 3 -- targets taught in RobotStudio, then corrected
  PERS tooldata tGripper:=[TRUE,[[0,0,100],[1,0,0,0]],[1.2,[0,0,40],[1,0,0,0],0,0,0]];
  TASK PERS wobjdata wTable := [FALSE, TRUE, "", [[300, -50, 100], [0.9659258, 0, 0, 0.258819]],
                                [[0,0,0],[1,0,0,0]]];
  CONST robtarget pPick:=[[259.03,78.27,335.36],[0.351462,0.1195093,0.9212198,0.1163872],[0,0,-1,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
  CONST robtarget pPlace := [ [ 117.36 , -161.99 , 436.46 ] , [ 0.7937217 , 0.2436302 , 0.5572698 , -0.0100305 ] , [ -1 , -1 , 0 , 1 ] , [ 9E9 , 9E9 , 9E9 , 9E9 , 9E9 , 9E9 ] ];
  CONST robtarget pVia:=[[334.74,47.85,436.35],[0.6899691,-0.0638338,0.7123726,0.1113244],[0,1,-2,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
  CONST robtarget pSpare:=[[300,0,400],[0,0,1,0],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]]; ! not used
  CONST jointtarget jHome:=[[0,0,0,0,30,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];

  PROC main()
    MoveAbsJ jHome\NoEOffs, v1000, fine, tool0;
    MoveJ pPick, v500, z10, tGripper\WObj:=wTable;   ! approach the part
    MoveL pPick, v100, fine, tGripper \WObj := wTable;
    MoveC pVia, pPlace, v200, z5, tGripper\WObj:=wTable;
    MoveL [[450.96,0,544],[0.5,0,0.8660254,0],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]], v200, fine, tool0;
    MoveL Offs(pPick, 0, 0, 50), v200, z10, tGripper\WObj:=wTable;
  ENDPROC
ENDMODULE
