/PROG  GIMBAL
/ATTR
OWNER		= MNEDITOR;
COMMENT		= "tool x axis vertical";
PROG_SIZE	= 812;
CREATE		= DATE 24-06-03  TIME 14:02:10;
MODIFIED	= DATE 24-06-03  TIME 14:02:10;
LINE_COUNT	= 3;
PROTECT		= READ_WRITE;
DEFAULT_GROUP	= 1,*,*,*,*;
/MN
   1:J P[1] 100% FINE    ;
   2:L P[2] 500mm/sec FINE    ;
   3:J P[1] 100% FINE    ;
/POS
P[1]{
   GP1:
	UF : 0, UT : 0,		CONFIG : 'N U T, 0, 0, 0',
	X =   900.000  mm,	Y =   100.000  mm,	Z =   700.000  mm,
	W =   168.020 deg,	P =    90.000 deg,	R =     0.000 deg
};
P[2]{
   GP1:
	UF : 0, UT : 0,		CONFIG : 'N U T, 0, 0, 0',
	X =   850.000  mm,	Y =  -150.000  mm,	Z =   500.000  mm,
	W =   -30.000 deg,	P =   -90.000 deg,	R =    45.000 deg
};
/END
