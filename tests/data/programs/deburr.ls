/PROG  DEBURR
/ATTR
OWNER		= MNEDITOR;
COMMENT		= "deburr edge";
PROG_SIZE	= 1024;
CREATE		= DATE 24-03-02  TIME 10:12:00;
MODIFIED	= DATE 24-03-02  TIME 10:12:00;
LINE_COUNT	= 6;
PROTECT		= READ_WRITE;
DEFAULT_GROUP	= 1,*,*,*,*;
/MN
   1:  UFRAME_NUM=2 ;
   2:  UTOOL_NUM=3 ;
   3:J P[4] 100% FINE    ;
   4:J P[1] 50% CNT50    ;
   5:L P[2:"edge start"] 250mm/sec FINE    ;
   6:  ! edge along the part ;
   7:L P[3] 100mm/sec FINE    ;
/POS
P[1]{
   GP1:
	UF : 2, UT : 3,		CONFIG : 'N U T, 0, 0, 0',
	X =   258.162  mm,	Y =  -152.307  mm,	Z =   768.048  mm,
	W =   155.954 deg,	P =   -25.329 deg,	R =   -23.887 deg
};
P[2:"edge start"]{
   GP1:
	UF : 2, UT : 3,		CONFIG : 'N U T, 0, 0, 0',
	X =   -85.883  mm,	Y =  -435.941  mm,	Z =  1161.612  mm,
	W =   145.701 deg,	P =   -61.003 deg,	R =    15.455 deg
};
P[3]{
   GP1:
	UF : 2, UT : 3,		CONFIG : 'F U T, 0, 0, 0',
	X =   466.842  mm,	Y =   -97.016  mm,	Z =   707.945  mm,
	W =  -145.294 deg,	P =   -63.494 deg,	R =   -19.857 deg
};
P[4]{
   GP1:
	UF : 0, UT : 3,	
	J1=     0.000 deg,	J2=     -.500 deg,	J3=     0.000 deg,
	J4=     0.000 deg,	J5=   -90.000 deg,	J6=     0.000 deg
};
/END
