MODULE MainModule
  ! Weld fixture, cell 7: targets taught in RobotStudio; tool and work object in CalibData
  CONST robtarget pApproach:=[[14.02,-35.25,269.41],[0.013947,-0.3680221,-0.9268213,-0.0732634],[-1,0,-1,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
  CONST robtarget pWeld10:=[[36.12,-59.24,181.95],[0.0963698,-0.3823751,-0.9162394,-0.0707642],[-1,0,-1,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
  ! offline points: placeholder configuration, reached with configuration monitoring off
  CONST robtarget pWeld20:=[[87.37,-12.92,165.47],[0.1425287,-0.3566147,-0.9200635,-0.0774257],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
  CONST robtarget pWeld30:=[[115.02,31.3,166.32],[0.1850563,-0.3216183,-0.9283026,-0.0238758],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
  CONST jointtarget jHome:=[[0,0,0,0,30,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];

  PROC main()
    MoveAbsJ jHome\NoEOffs, v1000, z50, tGun;
    MoveJ pApproach, v500, z20, tGun\WObj:=wFixture;
    MoveL \Conc, pWeld10, v100, fine, Tool:=tGun\WObj:=wFixture;
    ConfL \Off;
    MoveL pWeld20, v50, z1, tGun\WObj:=wFixture;
    MoveL pWeld30, v50, fine, tGun\WObj:=wFixture;
    ConfL \On;
    MoveJ RelTool(pApproach, 0, 0, -50), v500, z20, tGun\WObj:=wFixture;
    MoveAbsJ jHome\NoEOffs, v1000, fine, tGun;
  ENDPROC
ENDMODULE
