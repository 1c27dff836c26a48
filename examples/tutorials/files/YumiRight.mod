MODULE YumiRight
    ! The right arm of an ABB YuMi (IRB 14000): axis 7 is the first external axis (eax_a)
    CONST jointtarget jSync:=[[0,-130,30,0,40,0],[-135,9E+09,9E+09,9E+09,9E+09,9E+09]];
    CONST jointtarget jAbove:=[[-20,-100,20,30,50,10],[-110,9E+09,9E+09,9E+09,9E+09,9E+09]];
    CONST robtarget pPick:=[[-68.279,-413.987,392.746],[0.199253,0.900702,0.101124,0.372570],[-1,0,0,4],[-110,9E+09,9E+09,9E+09,9E+09,9E+09]];
    CONST robtarget pNearFlip:=[[-7.476,-410.416,336.224],[0.276675,0.896329,0.336680,0.081808],[-1,0,-1,4],[-100,9E+09,9E+09,9E+09,9E+09,9E+09]];
    CONST robtarget pPlace:=[[43.805,-454.988,271.047],[0.051494,-0.492991,-0.797727,-0.343424],[0,-1,-1,4],[-100,9E+09,9E+09,9E+09,9E+09,9E+09]];

    PROC main()
        MoveAbsJ jSync\NoEOffs, v200, fine, tool0;
        MoveAbsJ jAbove\NoEOffs, v200, fine, tool0;
        MoveJ pPick, v200, fine, tool0;
        MoveL pNearFlip, v200, fine, tool0;
        MoveL pPlace, v200, fine, tool0;
    ENDPROC
ENDMODULE
