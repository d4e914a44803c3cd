MODULE CellDemo
    !***********************************************************
    ! trackcal sample program (written for the project): an ABB
    ! IRB 120-3/0.58 (configs/robots/irb120.yaml) picks a part on
    ! a table and places it on a fixture. RobotWare 6 / 7.
    !***********************************************************

    ! tools: [robhold, [tframe trans, rot], [mass, cog, aom, ix, iy, iz]]
    PERS tooldata tGripper:=[TRUE,[[0,0,105.5],[1,0,0,0]],[0.5,[0,0,40],[1,0,0,0],0,0,0]];
    PERS tooldata tPen:=[TRUE,[[12.5,0,95],[0.9659258,0,0.258819,0]],[0.3,[5,0,45],[1,0,0,0],0,0,0]];

    ! work objects: [robhold, ufprog, ufmec, uframe, oframe]
    TASK PERS wobjdata wobjTable:=[FALSE,TRUE,"",[[350,-200,20],[0.9238795,0,0,0.3826834]],
                                  [[10,5,0],[1,0,0,0]]];
    TASK PERS wobjdata wobjFixture:=[FALSE,TRUE,"",[[300,150,100],[1,0,0,0]],[[0,0,0],[0.7071068,0,0,-0.7071068]]];

    ! speeds and zones of this cell
    CONST speeddata vApproach:=[400,200,5000,1000];
    CONST zonedata zCell:=[FALSE,5,8,8,0.8,8,0.8];
    VAR num nParts:=0;

    CONST jointtarget jHome:=[[0,0,0,0,30,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
    CONST robtarget pApproach:=[[94.18,16.3,262.55],[0.137208,0.3684,0.919447,0.008526],[-1,0,-1,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
    CONST robtarget pPick:=[[93.69,6.82,195.22],[0.115949,0.383882,0.915989,0.012443],[-1,0,-1,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
    CONST robtarget pCirc:=[[162.34,86.03,198.84],[0.058604,0.619083,0.781485,0.050822],[-1,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
    CONST robtarget pEnd:=[[185.94,172.44,205.72],[0,0.608761,0.793353,0],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
    PERS robtarget pPlace:=[[-60.33,61.04,187.22],[0.128565,0.318455,-0.939078,-0.013779],[0,-1,1,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];

    PROC main()
        ! start from the home position, then one cycle per part
        MoveAbsJ jHome\NoEOffs, v1000, z50, tGripper;
        WHILE nParts < 3 DO
            Pick;
            Place;
            nParts := nParts + 1;
        ENDWHILE
        MoveAbsJ jHome\NoEOffs, v1000, fine, tGripper;
    ENDPROC

    PROC Pick()
        MoveJ pApproach, vApproach, zCell, tGripper\WObj:=wobjTable;
        MoveL pPick, v100, fine, tGripper\WObj:=wobjTable;  ! grip here
        WaitTime 0.5;
        MoveL Offs(pPick,0,0,60), v200, z10, tGripper\WObj:=wobjTable;
        MoveC pCirc, pEnd, v200, z10, tGripper\WObj:=wobjTable;
    ENDPROC

    PROC Place()
        MoveJ RelTool(pPlace,0,0,-40), v500, z20, tPen\WObj:=wobjFixture;
        MoveL pPlace, v50, fine, tPen\WObj:=wobjFixture;
        ! a point taught on the line, kept inline
        MoveL [[64.81,119.11,195.35],[0.287702,-0.678039,-0.438472,-0.515009],[0,1,1,1],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]], v50, z1, tPen\WObj:=wobjFixture;
        IF nParts = 2 THEN
            MoveJ pPlace, v200, z20, tPen\WObj:=wobjFixture;
        ENDIF
    ENDPROC
ENDMODULE
